//! A bounded I2C master for the STM32F4's I2C peripheral (RM0090 §27, the "v1" I2C).
//!
//! stm32f4xx-hal 0.23's blocking driver polls the status flags without a bound: a slave
//! that holds SCL low in the middle of a transfer hangs the task (and, under the bus's
//! priority ceiling, every task below the DRDY interrupt) until the watchdog resets the
//! board. This driver runs the same register sequences with **every wait bounded by a
//! cycle budget** ([`BoundedI2c::new`]); a wait that runs out returns
//! [`Error::Timeout`] naming the step, the transfer ends with a STOP request, and
//! [`BoundedI2c::needs_clear`] tells [`super::i2c_bus::Guarded`] to clock the bus free
//! and re-initialise the peripheral at once instead of after three failures.
//!
//! Reception follows RM0090 §27.3.3's sequences for 1, 2 and ≥ 3 bytes (ACK cleared
//! before ADDR for one byte; POS for two; BTF before the last three), so the last byte is
//! NACKed however late a preempting interrupt lets the code run: a master that ACKs the
//! last byte leaves the slave driving SDA for one more, and the STOP cannot follow.
//!
//! The registers are reached through [`Regs`], so the whole driver is tested on the host
//! against a register model of the peripheral and a slave (`i2c_master_tests.rs`):
//! transfers of every length under random preemption delays, NACKs, arbitration loss and a
//! clock held low at any moment of a transfer.

use embedded_hal::i2c::{self, ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};

/// CR1: peripheral enable.
pub const CR1_PE: u16 = 1 << 0;
/// CR1: generate a (repeated) START.
pub const CR1_START: u16 = 1 << 8;
/// CR1: generate a STOP (cleared by the hardware once it is on the bus).
pub const CR1_STOP: u16 = 1 << 9;
/// CR1: ACK received bytes.
pub const CR1_ACK: u16 = 1 << 10;
/// CR1: ACK/NACK applies to the next byte (two-byte reception).
pub const CR1_POS: u16 = 1 << 11;
/// SR1: START sent.
pub const SR1_SB: u16 = 1 << 0;
/// SR1: address sent and ACKed.
pub const SR1_ADDR: u16 = 1 << 1;
/// SR1: byte transfer finished (data and shift register both full or both empty).
pub const SR1_BTF: u16 = 1 << 2;
/// SR1: a received byte waits in DR.
pub const SR1_RXNE: u16 = 1 << 6;
/// SR1: DR empty (transmitter).
pub const SR1_TXE: u16 = 1 << 7;
/// SR1: bus error (misplaced START/STOP).
pub const SR1_BERR: u16 = 1 << 8;
/// SR1: arbitration lost.
pub const SR1_ARLO: u16 = 1 << 9;
/// SR1: acknowledge failure (NACK).
pub const SR1_AF: u16 = 1 << 10;
/// SR1: overrun/underrun.
pub const SR1_OVR: u16 = 1 << 11;
/// SR2: bus busy.
pub const SR2_BUSY: u16 = 1 << 1;

/// The peripheral's registers and a free-running cycle counter.
///
/// Reading SR1 then writing DR clears SB; reading SR1 then SR2 clears ADDR; reading DR
/// clears RXNE (RM0090 §27.6.6–27.6.7): implementations must not read a register the
/// driver did not ask for.
pub trait Regs {
    /// Reads CR1.
    fn cr1(&mut self) -> u16;
    /// Writes CR1.
    fn set_cr1(&mut self, value: u16);
    /// Reads SR1.
    fn sr1(&mut self) -> u16;
    /// Writes SR1 (its error flags are cleared by writing 0).
    fn set_sr1(&mut self, value: u16);
    /// Reads SR2.
    fn sr2(&mut self) -> u16;
    /// Reads DR.
    fn dr(&mut self) -> u8;
    /// Writes DR.
    fn set_dr(&mut self, value: u8);
    /// A free-running cycle counter (wraps; the board's DWT CYCCNT).
    fn now(&mut self) -> u32;
    /// Runs `f` with interrupts masked: the errata's critical steps (ES0182 §2.5.x,
    /// AN2824), a few register accesses each, must end before the byte on the wire does.
    /// The default masks nothing (the host model).
    fn critical<T>(&mut self, f: impl FnOnce(&mut Self) -> T) -> T
    where
        Self: Sized,
    {
        f(self)
    }
}

/// CR1 read-modify-write.
fn modify<R: Regs>(regs: &mut R, set: u16, clear: u16) {
    let v = regs.cr1();
    regs.set_cr1((v & !clear) | set);
}

/// The step of a transfer that a wait belongs to (named in a timeout).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Step {
    /// A previous STOP still on the bus.
    PreviousStop,
    /// The START condition (the bus stayed busy or SCL low).
    Start,
    /// The address byte.
    Address,
    /// A data byte sent.
    Send,
    /// A data byte received.
    Receive,
    /// The STOP condition.
    Stop,
}

/// A bounded transfer's error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// A wait ran out of its cycle budget: the bus or the peripheral is stuck.
    #[error("I2C timeout at {0:?}")]
    Timeout(Step),
    /// The slave did not acknowledge.
    #[error("I2C NACK ({0:?})")]
    Nack(Nack),
    /// Another master won the bus.
    #[error("I2C arbitration lost")]
    ArbitrationLoss,
    /// The peripheral reported an overrun.
    #[error("I2C overrun")]
    Overrun,
    /// A read of zero bytes was asked for (the bus cannot end a read without a byte).
    #[error("I2C read of zero bytes")]
    EmptyRead,
    /// The owner has no peripheral in place (before boot set it up, or its pins were
    /// lost in a bus clear).
    #[error("I2C bus not in place")]
    Unavailable,
}

/// What a NACK answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Nack {
    /// The address (no such device, or it is busy).
    Address,
    /// A data byte.
    Data,
}

impl i2c::Error for Error {
    fn kind(&self) -> ErrorKind {
        match self {
            Error::Timeout(_) => ErrorKind::Bus,
            Error::Nack(Nack::Address) => ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address),
            Error::Nack(Nack::Data) => ErrorKind::NoAcknowledge(NoAcknowledgeSource::Data),
            Error::ArbitrationLoss => ErrorKind::ArbitrationLoss,
            Error::Overrun => ErrorKind::Overrun,
            Error::EmptyRead => ErrorKind::Other,
            Error::Unavailable => ErrorKind::Bus,
        }
    }
}

/// Cycle budget of one wait on the board: 1 ms at 168 MHz. The longest wait that can
/// succeed is one byte and its ACK on the wire (22.5 µs at 400 kHz); no device on this bus
/// (BMI160, LSM303AGR, SSD1306) stretches the clock, so 1 ms is ×44 of that and still a
/// tenth of the IMU tick's period.
pub const BOARD_BUDGET_CYCLES: u32 = 168_000;

/// The STM32F4 I2C master with every flag wait bounded.
#[derive(Debug)]
pub struct BoundedI2c<R> {
    regs: R,
    budget: u32,
}

impl<R: Regs> BoundedI2c<R> {
    /// Drives an enabled, configured peripheral (clock, CCR, TRISE, PE set, e.g. by the
    /// HAL's constructor); each wait gives up after `budget_cycles` of [`Regs::now`].
    pub fn new(regs: R, budget_cycles: u32) -> Self {
        Self {
            regs,
            budget: budget_cycles,
        }
    }

    /// The registers (for the owner's re-initialisation and the tests).
    pub fn regs(&mut self) -> &mut R {
        &mut self.regs
    }

    /// Hands the registers back.
    pub fn release(self) -> R {
        self.regs
    }

    /// Whether `e` leaves the bus or the peripheral in an unknown state, so that the bus
    /// must be cleared and the peripheral re-initialised before the next transfer.
    pub fn needs_clear(e: &Error) -> bool {
        matches!(
            e,
            Error::Timeout(_) | Error::ArbitrationLoss | Error::Overrun
        )
    }

    fn modify_cr1(&mut self, set: u16, clear: u16) {
        modify(&mut self.regs, set, clear);
    }

    /// Reads SR1 and turns an error flag into an error (clearing it).
    fn sr1_checked(&mut self, step: Step) -> Result<u16, Error> {
        let sr1 = self.regs.sr1();
        let err = if sr1 & SR1_ARLO != 0 {
            Some((SR1_ARLO, Error::ArbitrationLoss))
        } else if sr1 & SR1_AF != 0 {
            let n = if step == Step::Address {
                Nack::Address
            } else {
                Nack::Data
            };
            Some((SR1_AF, Error::Nack(n)))
        } else if sr1 & SR1_OVR != 0 {
            Some((SR1_OVR, Error::Overrun))
        } else {
            None
        };
        // BERR is cleared and ignored, as the HAL does: ES0182 §2.5.x reports spurious
        // bus errors, and a real one shows up as a NACK or a timeout anyway.
        let flags = err.map_or(0, |(f, _)| f) | (sr1 & SR1_BERR);
        if flags != 0 {
            self.regs.set_sr1(!flags);
        }
        match err {
            Some((_, e)) => Err(e),
            None => Ok(sr1),
        }
    }

    /// Polls SR1 until `mask` is set, an error flag shows or the budget runs out.
    fn wait_sr1(&mut self, mask: u16, step: Step) -> Result<(), Error> {
        let t0 = self.regs.now();
        loop {
            if self.sr1_checked(step)? & mask != 0 {
                return Ok(());
            }
            if self.regs.now().wrapping_sub(t0) > self.budget {
                return Err(Error::Timeout(step));
            }
        }
    }

    /// Waits until the hardware has cleared CR1.STOP (the STOP is on the bus).
    fn wait_stop_done(&mut self, step: Step) -> Result<(), Error> {
        let t0 = self.regs.now();
        while self.regs.cr1() & CR1_STOP != 0 {
            if self.regs.now().wrapping_sub(t0) > self.budget {
                return Err(Error::Timeout(step));
            }
        }
        Ok(())
    }

    /// After SB: sends the address byte and waits for ADDR (not yet cleared).
    fn address(&mut self, address: u8, read: bool) -> Result<(), Error> {
        self.wait_sr1(SR1_SB, Step::Start)?;
        self.regs.set_dr((address << 1) | u8::from(read));
        self.wait_sr1(SR1_ADDR, Step::Address)
    }

    /// Writes the condition that ends a segment (STOP after the last, else a repeated
    /// START with the next segment's reception bits) in one CR1 write: a second
    /// read-modify-write while START or STOP is pending could request it twice.
    fn end_condition(&mut self, end: Cr1Bits) {
        self.modify_cr1(end.set, end.clear);
    }

    fn write_segment(
        &mut self,
        address: u8,
        ops: &[Operation<'_>],
        end: Cr1Bits,
    ) -> Result<(), Error> {
        self.address(address, false)?;
        let _ = self.regs.sr2(); // clears ADDR (after the SR1 read of the wait)
        for op in ops {
            if let Operation::Write(bytes) = op {
                for &b in bytes.iter() {
                    self.wait_sr1(SR1_TXE, Step::Send)?;
                    self.regs.set_dr(b);
                }
            }
        }
        // BTF: the last byte is out and ACKed (TXE alone would cut it short). A write of
        // no bytes (an address probe) has nothing to wait for.
        if ops
            .iter()
            .any(|o| matches!(o, Operation::Write(b) if !b.is_empty()))
        {
            self.wait_sr1(SR1_BTF, Step::Send)?;
        }
        self.end_condition(end);
        Ok(())
    }

    /// Reads a run of read operations; ACK and POS were set with its START
    /// ([`rx_bits`]).
    fn read_segment(
        &mut self,
        address: u8,
        ops: &mut [Operation<'_>],
        end: Cr1Bits,
    ) -> Result<(), Error> {
        let n = read_len(ops);
        self.address(address, true)?;
        match n {
            0 => return Err(Error::EmptyRead),
            1 => {
                // ACK already clear: the byte is NACKed; STOP/START right after ADDR is
                // cleared, before the byte ends (AN2824 EV6_3).
                self.regs.critical(|r| {
                    let _ = r.sr2();
                    modify(r, end.set, end.clear);
                });
                self.wait_sr1(SR1_RXNE, Step::Receive)?;
                put(ops, 0, self.regs.dr());
            }
            2 => {
                // With POS, ACK cleared while ADDR still stretches SCL NACKs the second
                // byte; the first keeps the ACK it had when the address was ACKed.
                self.modify_cr1(0, CR1_ACK);
                let _ = self.regs.sr2();
                self.wait_sr1(SR1_BTF, Step::Receive)?;
                let first = self.regs.critical(|r| {
                    modify(r, end.set, end.clear);
                    r.dr()
                });
                put(ops, 0, first);
                put(ops, 1, self.regs.dr());
            }
            _ => {
                let _ = self.regs.sr2();
                let mut k = 0;
                while n - k > 3 {
                    self.wait_sr1(SR1_RXNE, Step::Receive)?;
                    put(ops, k, self.regs.dr());
                    k += 1;
                }
                // Byte n-2 in DR, n-1 in the shift register, SCL stretched: byte n has
                // not started, so clearing ACK now NACKs it.
                self.wait_sr1(SR1_BTF, Step::Receive)?;
                // AN2824 EV7_2: ACK off, byte n-2 read (byte n starts), STOP, byte n-1
                // read, with nothing in between.
                let (a, b) = self.regs.critical(|r| {
                    modify(r, 0, CR1_ACK);
                    let a = r.dr();
                    modify(r, end.set, end.clear);
                    (a, r.dr())
                });
                put(ops, k, a);
                put(ops, k + 1, b);
                self.wait_sr1(SR1_RXNE, Step::Receive)?;
                put(ops, k + 2, self.regs.dr());
            }
        }
        Ok(())
    }

    fn run(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), Error> {
        self.wait_stop_done(Step::PreviousStop)?;
        // Stale error flags from an earlier transfer must not fail this one.
        self.regs.set_sr1(0);
        let mut segments = operations.chunk_by_mut(same_direction).peekable();
        if let Some(first) = segments.peek() {
            let bits = start_bits(first);
            self.end_condition(bits);
        }
        while let Some(seg) = segments.next() {
            let end = segments.peek().map_or(
                Cr1Bits {
                    set: CR1_STOP,
                    clear: CR1_POS,
                },
                |next| start_bits(next),
            );
            if is_read(seg) {
                self.read_segment(address, seg, end)?;
            } else {
                self.write_segment(address, seg, end)?;
            }
        }
        self.wait_stop_done(Step::Stop)
    }
}

/// CR1 bits to set and clear in one write.
#[derive(Debug, Clone, Copy)]
struct Cr1Bits {
    set: u16,
    clear: u16,
}

/// The START request of a segment with the reception bits it needs (RM0090 §27.3.3): one
/// byte NACKed from the start (ACK clear), two with POS, more with ACK.
fn start_bits(seg: &[Operation<'_>]) -> Cr1Bits {
    let (set, clear) = if !is_read(seg) {
        (0, CR1_POS)
    } else {
        match read_len(seg) {
            1 => (0, CR1_ACK | CR1_POS),
            2 => (CR1_ACK | CR1_POS, 0),
            _ => (CR1_ACK, CR1_POS),
        }
    };
    Cr1Bits {
        set: CR1_START | set,
        clear,
    }
}

/// Whether a run of read operations has no byte to read (nothing is sent then).
fn has_empty_read(ops: &[Operation<'_>]) -> bool {
    ops.chunk_by(same_direction)
        .any(|seg| is_read(seg) && read_len(seg) == 0)
}

/// Whether a segment reads.
fn is_read(seg: &[Operation<'_>]) -> bool {
    matches!(seg.first(), Some(Operation::Read(_)))
}

/// Whether two operations go the same way (one segment: no START between them).
fn same_direction(a: &Operation<'_>, b: &Operation<'_>) -> bool {
    matches!(a, Operation::Read(_)) == matches!(b, Operation::Read(_))
}

/// Bytes to read in a run of read operations.
fn read_len(ops: &[Operation<'_>]) -> usize {
    ops.iter()
        .map(|o| match o {
            Operation::Read(b) => b.len(),
            Operation::Write(_) => 0,
        })
        .sum()
}

/// Stores the `k`-th byte of a run of read operations.
fn put(ops: &mut [Operation<'_>], mut k: usize, byte: u8) {
    for o in ops.iter_mut() {
        if let Operation::Read(b) = o {
            if let Some(slot) = b.get_mut(k) {
                *slot = byte;
                return;
            }
            k -= b.len();
        }
    }
}

impl<R> ErrorType for BoundedI2c<R> {
    type Error = Error;
}

impl<R: Regs> I2c for BoundedI2c<R> {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        if operations.is_empty() {
            return Ok(());
        }
        if has_empty_read(operations) {
            return Err(Error::EmptyRead);
        }
        let r = self.run(address, operations);
        if let Err(e) = r {
            // A NACK leaves the master holding the bus; a timeout, an unknown state. A
            // STOP request releases the bus in the first case and is harmless in the
            // second (the owner clears the bus and resets the peripheral anyway). After
            // an arbitration loss the peripheral is a slave already: no STOP.
            if e != Error::ArbitrationLoss {
                self.modify_cr1(CR1_STOP, CR1_START | CR1_POS);
                if matches!(e, Error::Nack(_)) {
                    let _ = self.wait_stop_done(Step::Stop);
                }
            }
        }
        r
    }
}

#[cfg(test)]
#[path = "i2c_master_tests.rs"]
mod tests;
