//! A bounded SPI master for the STM32F4's SPI peripheral (RM0090 §28), full duplex, 8-bit
//! frames: the antenna ADC's bus.
//!
//! stm32f4xx-hal 0.23's blocking transfers poll TXE and RXNE without a bound. The master
//! clocks every byte itself, so on a working peripheral each wait ends within a byte time;
//! but a peripheral that stops (SPE cleared by a mode fault, a clock switched off) leaves
//! RXNE clear for good and the DRDY interrupt, the highest priority on the board, spins
//! until the watchdog resets. Here every wait gives up after a cycle budget
//! ([`BoundedSpi::new`]) and the transfer returns [`SpiError::Timeout`]; the ADC driver
//! counts the frame as failed and the health monitor reports an ADC fault when that
//! persists ([`super::health`]).
//!
//! One byte is written only after the previous one was read, so a preempting interrupt can
//! stretch a transfer but never overrun the receive register.

use embedded_hal::spi::{self, ErrorKind, ErrorType, SpiBus};

/// SR: receive buffer not empty.
pub const SR_RXNE: u16 = 1 << 0;
/// SR: transmit buffer empty.
pub const SR_TXE: u16 = 1 << 1;
/// SR: mode fault (NSS pulled low in master mode: the peripheral left master mode).
pub const SR_MODF: u16 = 1 << 5;
/// SR: overrun.
pub const SR_OVR: u16 = 1 << 6;
/// SR: busy.
pub const SR_BSY: u16 = 1 << 7;

/// Cycle budget of one wait on the board: 100 µs at 168 MHz, 100 byte times at the ADC's
/// 8 MHz clock (a byte takes 1 µs; the DRDY task's whole frame, 18 bytes, ≈ 23 µs).
pub const BOARD_BUDGET_CYCLES: u32 = 16_800;

/// The peripheral's registers and a free-running cycle counter.
pub trait SpiRegs {
    /// Reads SR.
    fn sr(&mut self) -> u16;
    /// Reads DR (clears RXNE; after SR, clears OVR).
    fn dr(&mut self) -> u8;
    /// Writes DR.
    fn set_dr(&mut self, value: u8);
    /// Writes CR1 with its own value (after an SR read, clears MODF).
    fn rewrite_cr1(&mut self);
    /// A free-running cycle counter (wraps; the board's DWT CYCCNT).
    fn now(&mut self) -> u32;
}

/// What a wait was for (named in a timeout).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SpiStep {
    /// Room in the transmit buffer.
    Send,
    /// A received byte.
    Receive,
    /// The end of the last byte (BSY clear).
    Idle,
}

/// A bounded SPI transfer's error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SpiError {
    /// A wait ran out of its budget: the peripheral stopped clocking.
    #[error("SPI timeout at {0:?}")]
    Timeout(SpiStep),
    /// A received byte was overwritten before it was read.
    #[error("SPI overrun")]
    Overrun,
    /// NSS went low in master mode: the peripheral left master mode and must be set up
    /// again.
    #[error("SPI mode fault")]
    ModeFault,
}

impl spi::Error for SpiError {
    fn kind(&self) -> ErrorKind {
        match self {
            SpiError::Timeout(_) => ErrorKind::Other,
            SpiError::Overrun => ErrorKind::Overrun,
            SpiError::ModeFault => ErrorKind::ModeFault,
        }
    }
}

/// The STM32F4 SPI master with every flag wait bounded.
#[derive(Debug)]
pub struct BoundedSpi<R> {
    regs: R,
    budget: u32,
}

impl<R: SpiRegs> BoundedSpi<R> {
    /// Drives an enabled, configured master (8-bit frames, software NSS high, e.g. by the
    /// HAL's constructor); each wait gives up after `budget_cycles` of [`SpiRegs::now`].
    pub fn new(regs: R, budget_cycles: u32) -> Self {
        Self {
            regs,
            budget: budget_cycles,
        }
    }

    /// The registers (for the tests).
    pub fn regs(&mut self) -> &mut R {
        &mut self.regs
    }

    /// Polls SR until `mask` is set or an error flag shows, within the budget.
    fn wait(&mut self, mask: u16, step: SpiStep) -> Result<(), SpiError> {
        let t0 = self.regs.now();
        loop {
            let sr = self.regs.sr();
            if sr & SR_OVR != 0 {
                // DR then SR (read above) clears OVR.
                let _ = self.regs.dr();
                let _ = self.regs.sr();
                return Err(SpiError::Overrun);
            }
            if sr & SR_MODF != 0 {
                self.regs.rewrite_cr1();
                return Err(SpiError::ModeFault);
            }
            if sr & mask != 0 {
                return Ok(());
            }
            if self.regs.now().wrapping_sub(t0) > self.budget {
                return Err(SpiError::Timeout(step));
            }
        }
    }

    /// One byte out, one byte in.
    fn exchange(&mut self, out: u8) -> Result<u8, SpiError> {
        self.wait(SR_TXE, SpiStep::Send)?;
        self.regs.set_dr(out);
        self.wait(SR_RXNE, SpiStep::Receive)?;
        Ok(self.regs.dr())
    }

    /// Leaves no stale byte behind a failed transfer (the next one starts clean).
    fn drain(&mut self) {
        if self.regs.sr() & SR_RXNE != 0 {
            let _ = self.regs.dr();
        }
    }

    fn run(&mut self, f: impl FnOnce(&mut Self) -> Result<(), SpiError>) -> Result<(), SpiError> {
        let r = f(self);
        if r.is_err() {
            self.drain();
        }
        r
    }
}

impl<R> ErrorType for BoundedSpi<R> {
    type Error = SpiError;
}

impl<R: SpiRegs> SpiBus<u8> for BoundedSpi<R> {
    fn read(&mut self, words: &mut [u8]) -> Result<(), SpiError> {
        self.run(|s| {
            for w in words.iter_mut() {
                *w = s.exchange(0)?;
            }
            Ok(())
        })
    }

    fn write(&mut self, words: &[u8]) -> Result<(), SpiError> {
        self.run(|s| {
            for &w in words {
                s.exchange(w)?;
            }
            Ok(())
        })
    }

    fn transfer(&mut self, read: &mut [u8], write: &[u8]) -> Result<(), SpiError> {
        self.run(|s| {
            for i in 0..read.len().max(write.len()) {
                let b = s.exchange(write.get(i).copied().unwrap_or(0))?;
                if let Some(r) = read.get_mut(i) {
                    *r = b;
                }
            }
            Ok(())
        })
    }

    fn transfer_in_place(&mut self, words: &mut [u8]) -> Result<(), SpiError> {
        self.run(|s| {
            for w in words.iter_mut() {
                *w = s.exchange(*w)?;
            }
            Ok(())
        })
    }

    fn flush(&mut self) -> Result<(), SpiError> {
        // Every byte was read back, so the bus is idle once BSY drops.
        let t0 = self.regs.now();
        while self.regs.sr() & SR_BSY != 0 {
            if self.regs.now().wrapping_sub(t0) > self.budget {
                return Err(SpiError::Timeout(SpiStep::Idle));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::SmallRng;
    use rand::{Rng, SeedableRng};
    extern crate std;
    use std::vec;
    use std::vec::Vec;

    const ACCESS: u32 = 12;
    /// One byte at 8 MHz in 168 MHz cycles.
    const BYTE: u32 = 168;

    /// The SPI peripheral (transmit buffer, shift register, receive buffer) and a slave
    /// that answers each byte with its complement, advanced by the register accesses.
    struct Model {
        now: u32,
        rng: SmallRng,
        stall: (f64, u32),
        tx: Option<u8>,
        shift: Option<(u32, u8)>,
        rx: Option<u8>,
        ovr: bool,
        modf: bool,
        /// From this cycle on the peripheral stops (SPE cleared, clock off).
        stop_at: Option<u32>,
        sent: Vec<u8>,
        accesses: u64,
    }

    impl Model {
        fn new(seed: u64, stall: (f64, u32)) -> Self {
            Self {
                now: 0,
                rng: SmallRng::seed_from_u64(seed),
                stall,
                tx: None,
                shift: None,
                rx: None,
                ovr: false,
                modf: false,
                stop_at: None,
                sent: Vec::new(),
                accesses: 0,
            }
        }

        fn tick(&mut self) {
            self.accesses += 1;
            assert!(self.accesses < 1_000_000, "driver loops without a bound");
            if self.rng.random_bool(self.stall.0) {
                self.now += self.rng.random_range(0..=self.stall.1);
            }
            self.now += ACCESS;
            self.advance();
        }

        fn stopped(&self, t: u32) -> bool {
            self.stop_at.is_some_and(|s| t >= s)
        }

        fn advance(&mut self) {
            loop {
                match self.shift {
                    Some((end, b)) if end <= self.now && !self.stopped(end) => {
                        self.sent.push(b);
                        if self.rx.is_some() {
                            self.ovr = true;
                        }
                        self.rx = Some(!b);
                        self.shift = None;
                    }
                    Some(_) => return,
                    None => match self.tx.take() {
                        Some(b) if !self.stopped(self.now) => {
                            self.shift = Some((self.now + BYTE, b));
                        }
                        other => {
                            self.tx = other;
                            return;
                        }
                    },
                }
            }
        }
    }

    impl SpiRegs for Model {
        fn sr(&mut self) -> u16 {
            self.tick();
            let mut sr = 0;
            if self.rx.is_some() {
                sr |= SR_RXNE;
            }
            if self.tx.is_none() {
                sr |= SR_TXE;
            }
            if self.shift.is_some() || self.tx.is_some() {
                sr |= SR_BSY;
            }
            if self.ovr {
                sr |= SR_OVR;
            }
            if self.modf {
                sr |= SR_MODF;
            }
            sr
        }
        fn dr(&mut self) -> u8 {
            self.tick();
            self.ovr = false;
            self.rx.take().unwrap_or(0)
        }
        fn set_dr(&mut self, value: u8) {
            self.tick();
            assert!(self.tx.is_none(), "DR written while full");
            self.tx = Some(value);
            self.advance();
        }
        fn rewrite_cr1(&mut self) {
            self.tick();
            self.modf = false;
        }
        fn now(&mut self) -> u32 {
            self.tick();
            self.now
        }
    }

    #[test]
    fn transfers_of_every_shape_are_exact_under_random_preemption() {
        for seed in 0..300u64 {
            let mut rng = SmallRng::seed_from_u64(seed);
            // Preemptions of up to 40 byte times (the DRDY task preempts nothing, but
            // the test holds the driver to any caller's).
            let mut spi = BoundedSpi::new(Model::new(seed, (0.1, 40 * BYTE)), BOARD_BUDGET_CYCLES);
            let out: Vec<u8> = (0..rng.random_range(1..40)).map(|_| rng.random()).collect();
            let mut back = vec![0u8; rng.random_range(0..40)];
            match seed % 4 {
                0 => spi.transfer(&mut back, &out).unwrap(),
                1 => spi.write(&out).unwrap(),
                2 => spi.read(&mut back).unwrap(),
                _ => {
                    back = out.clone();
                    spi.transfer_in_place(&mut back).unwrap();
                }
            }
            spi.flush().unwrap();
            let m = spi.regs();
            let n = match seed % 4 {
                0 => out.len().max(back.len()),
                1 => out.len(),
                _ => back.len(),
            };
            assert_eq!(m.sent.len(), n, "seed {seed}: bytes clocked");
            if seed % 4 != 2 {
                assert_eq!(m.sent[..out.len()], out[..], "seed {seed}: bytes sent");
            }
            if seed % 4 != 1 {
                // Each byte read is the slave's answer to the byte sent with it.
                for (i, b) in back.iter().enumerate() {
                    assert_eq!(*b, !m.sent[i], "seed {seed}: byte {i}");
                }
            }
            assert!(!m.ovr && m.rx.is_none(), "seed {seed}: a byte left behind");
        }
    }

    #[test]
    fn a_stopped_peripheral_is_a_timeout_within_one_budget() {
        for seed in 0..200u64 {
            let mut rng = SmallRng::seed_from_u64(seed);
            let mut spi = BoundedSpi::new(Model::new(seed, (0.05, 5 * BYTE)), BOARD_BUDGET_CYCLES);
            let stop = rng.random_range(0..18 * (BYTE + 10 * ACCESS));
            spi.regs().stop_at = Some(stop);
            let mut frame = [0u8; 18];
            match spi.transfer_in_place(&mut frame) {
                Ok(()) => assert_eq!(spi.regs().sent.len(), 18),
                Err(SpiError::Timeout(step)) => {
                    assert_eq!(step, SpiStep::Receive, "seed {seed}");
                    let late = spi.regs().now - stop;
                    assert!(
                        late <= BOARD_BUDGET_CYCLES + 20 * BYTE,
                        "seed {seed}: {late}"
                    );
                }
                Err(e) => panic!("seed {seed}: {e}"),
            }
        }
    }

    #[test]
    fn a_mode_fault_and_an_overrun_are_errors_and_cleared() {
        let mut spi = BoundedSpi::new(Model::new(1, (0.0, 0)), BOARD_BUDGET_CYCLES);
        spi.regs().modf = true;
        assert_eq!(spi.write(&[1, 2]), Err(SpiError::ModeFault));
        assert!(!spi.regs().modf);
        assert_eq!(spi::Error::kind(&SpiError::ModeFault), ErrorKind::ModeFault);
        // A stale byte and an overrun from outside this driver: reported, then cleared.
        spi.regs().rx = Some(7);
        spi.regs().ovr = true;
        assert_eq!(spi.write(&[1]), Err(SpiError::Overrun));
        assert_eq!(spi.write(&[1, 2, 3]), Ok(()));
        assert_eq!(spi.regs().sent, [1, 2, 3]);
    }
}
