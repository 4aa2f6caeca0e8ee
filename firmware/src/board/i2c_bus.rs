//! The shared I2C bus (IMU and display) guarded against a stuck bus.
//!
//! A slave interrupted in the middle of a read (the MCU reset by the watchdog, a glitch on
//! SCL) keeps driving SDA low while it waits for clock pulses that never come; the master
//! then sees a busy bus forever and, in the STM32 HAL's blocking driver, waits for a START
//! that never happens. Two defences:
//! - **before every transfer**, [`Guarded`] checks that both lines are idle (high), which
//!   takes a GPIO read, so a stuck bus is an error value at once instead of a hang;
//! - **recovery** ([`clear_bus`]): the pins are taken from the I2C peripheral as
//!   open-drain GPIOs, SCL is clocked (at most 9 pulses, NXP UM10204 §3.1.16 "bus clear")
//!   until the slave releases SDA, a STOP is generated, and the peripheral is
//!   re-initialised. [`Guarded`] recovers when the lines are stuck or after
//!   [`Guarded::ERRORS_BEFORE_RECOVERY`] failed transfers in a row, counts every
//!   recovery ([`BusStats`]) and raises a flag so that the owner re-initialises the
//!   devices (their registers may have been reset with the bus, or the interrupted
//!   transfer left them half-configured).
//!
//! A slave that holds SCL low for good (clock stretching without end) cannot be clocked
//! free: [`ClearError::SclHeldLow`]. A transfer that hangs inside the HAL after the
//! idle check is not bounded here: on an idle bus the master's own START, address and data
//! complete by themselves, so such a hang needs a slave holding SCL low — which no clear
//! cures either. The progress-checked watchdog ([`super::watchdog`]) resets the board
//! then; at the next boot the idle check finds SCL low and the guard refuses transfers
//! (an I2C fault, not a hang).

use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{InputPin, OutputPin};
use embedded_hal::i2c::{self, ErrorKind, ErrorType, I2c, Operation, SevenBitAddress};

/// Half a period of the recovery clock, ns (≈ 100 kHz: every I2C slave follows it).
pub const HALF_PERIOD_NS: u32 = 5_000;
/// How long a slave may stretch SCL during a recovery, in half periods (1 ms).
pub const STRETCH_LIMIT: u32 = 200;

/// A bus clear that succeeded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cleared {
    /// SCL pulses it took for the slave to release SDA (0: SDA was free).
    pub pulses: u8,
}

/// Why a bus clear failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClearError {
    /// SCL stays low: a slave stretches the clock without end (or SCL is shorted).
    #[error("SCL held low (a slave stretching the clock without end, or a short)")]
    SclHeldLow,
    /// SDA is still low after 9 pulses and a STOP (or SDA is shorted).
    #[error("SDA still low after 9 clock pulses and a STOP")]
    SdaHeldLow,
    /// A GPIO reported an error (or the pins could not be taken from the peripheral).
    #[error("the bus pins could not be driven or taken from the peripheral")]
    Pin,
}

/// Clocks a stuck I2C bus free: SCL pulsed until SDA is released (at most 9 pulses), then
/// a STOP; both lines must be high at the end. `scl` and `sda` are open-drain outputs
/// whose level can be read back.
pub fn clear_bus<Scl, Sda, D>(
    scl: &mut Scl,
    sda: &mut Sda,
    delay: &mut D,
) -> Result<Cleared, ClearError>
where
    Scl: OutputPin + InputPin,
    Sda: OutputPin + InputPin,
    D: DelayNs,
{
    scl.set_high().map_err(pin)?;
    sda.set_high().map_err(pin)?;
    delay.delay_ns(HALF_PERIOD_NS);
    wait_scl_high(scl, delay)?;
    let mut pulses = 0u8;
    while pulses < 9 && sda.is_low().map_err(pin)? {
        scl.set_low().map_err(pin)?;
        delay.delay_ns(HALF_PERIOD_NS);
        scl.set_high().map_err(pin)?;
        delay.delay_ns(HALF_PERIOD_NS);
        wait_scl_high(scl, delay)?;
        pulses += 1;
    }
    // STOP: SDA rises while SCL is high (SDA is first pulled low with SCL low, so that
    // the falling edge is not a START).
    scl.set_low().map_err(pin)?;
    delay.delay_ns(HALF_PERIOD_NS);
    sda.set_low().map_err(pin)?;
    delay.delay_ns(HALF_PERIOD_NS);
    scl.set_high().map_err(pin)?;
    delay.delay_ns(HALF_PERIOD_NS);
    wait_scl_high(scl, delay)?;
    sda.set_high().map_err(pin)?;
    delay.delay_ns(HALF_PERIOD_NS);
    if sda.is_low().map_err(pin)? {
        return Err(ClearError::SdaHeldLow);
    }
    Ok(Cleared { pulses })
}

/// Any GPIO error is a [`ClearError::Pin`].
fn pin<E>(_: E) -> ClearError {
    ClearError::Pin
}

/// Waits (bounded: [`STRETCH_LIMIT`] half periods) for a released SCL to read high.
fn wait_scl_high<Scl: InputPin, D: DelayNs>(
    scl: &mut Scl,
    delay: &mut D,
) -> Result<(), ClearError> {
    for _ in 0..STRETCH_LIMIT {
        if scl.is_high().map_err(pin)? {
            return Ok(());
        }
        delay.delay_ns(HALF_PERIOD_NS);
    }
    Err(ClearError::SclHeldLow)
}

/// An I2C bus whose lines can be read and which can be cleared and re-initialised.
pub trait Recoverable: I2c {
    /// Whether SCL and SDA both read high (no transfer is running when this is asked).
    fn lines_idle(&mut self) -> bool;
    /// Takes the pins from the peripheral, runs [`clear_bus`] on them and re-initialises
    /// the peripheral (also when the clear failed, so that the next check sees the
    /// lines again).
    fn clear_and_reinit(&mut self) -> Result<Cleared, ClearError>;
    /// Whether a transfer's error left the bus or the peripheral in an unknown state (a
    /// timeout), so that the bus is cleared at once rather than after
    /// [`Guarded::ERRORS_BEFORE_RECOVERY`] failures.
    fn needs_clear(&self, _error: &Self::Error) -> bool {
        false
    }
}

/// Counts of the bus's troubles since boot (shown on the display and logged).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusStats {
    /// Transfers that failed (bus errors and refusals on a stuck bus).
    pub errors: u32,
    /// Times the lines were found stuck before a transfer.
    pub stuck: u32,
    /// Bus clears that freed the bus.
    pub recoveries: u32,
    /// Bus clears that did not.
    pub failed_recoveries: u32,
}

/// A transfer's error on a guarded bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GuardError<E: core::fmt::Debug> {
    /// The bus's own error.
    #[error("I2C error: {0:?}")]
    Bus(E),
    /// The lines were stuck before the transfer and a clear did not free them: nothing
    /// was sent.
    #[error("I2C lines stuck and not freed: {0}")]
    Stuck(ClearError),
}

impl<E: i2c::Error> i2c::Error for GuardError<E> {
    fn kind(&self) -> ErrorKind {
        match self {
            GuardError::Bus(e) => e.kind(),
            GuardError::Stuck(_) => ErrorKind::Bus,
        }
    }
}

/// A [`Recoverable`] bus that checks its lines before every transfer and recovers.
#[derive(Debug)]
pub struct Guarded<B> {
    bus: B,
    stats: BusStats,
    errors_in_row: u8,
    reinit_devices: bool,
    last_clear: Option<Result<Cleared, ClearError>>,
    /// A clear failed and no transfer has succeeded since.
    stuck: bool,
}

impl<B: Recoverable> Guarded<B> {
    /// Failed transfers in a row after which the bus is cleared (a slave that misread a
    /// START answers nothing until it is clocked back to idle).
    pub const ERRORS_BEFORE_RECOVERY: u8 = 3;

    /// Guards `bus`.
    pub fn new(bus: B) -> Self {
        Self {
            bus,
            stats: BusStats::default(),
            errors_in_row: 0,
            reinit_devices: false,
            last_clear: None,
            stuck: false,
        }
    }

    /// Whether the bus is stuck: a clear failed and no transfer has succeeded since (a
    /// sensor fault: the devices on it are unreachable).
    pub fn stuck(&self) -> bool {
        self.stuck
    }

    /// The counts since boot.
    pub fn stats(&self) -> BusStats {
        self.stats
    }

    /// The outcome of the last bus clear, if any.
    pub fn last_clear(&self) -> Option<Result<Cleared, ClearError>> {
        self.last_clear
    }

    /// Whether a clear happened since the last call: the devices on the bus must be
    /// re-initialised. Clears the flag.
    pub fn take_reinit(&mut self) -> bool {
        core::mem::take(&mut self.reinit_devices)
    }

    /// The guarded bus (for tests and the owner's own checks).
    pub fn inner(&mut self) -> &mut B {
        &mut self.bus
    }

    fn clear(&mut self) -> Result<Cleared, ClearError> {
        let r = self.bus.clear_and_reinit();
        match r {
            Ok(_) => self.stats.recoveries += 1,
            Err(_) => {
                self.stats.failed_recoveries += 1;
                self.stuck = true;
            }
        }
        self.last_clear = Some(r);
        self.reinit_devices = true;
        self.errors_in_row = 0;
        r
    }

    /// Runs `f` on the bus once its lines are idle (clearing them first if they are
    /// not), and books the outcome.
    fn guarded<T>(
        &mut self,
        f: impl FnOnce(&mut B) -> Result<T, B::Error>,
    ) -> Result<T, GuardError<B::Error>> {
        if !self.bus.lines_idle() {
            self.stats.stuck += 1;
            let cleared = self.clear();
            if let Err(e) = cleared.and_then(|c| {
                if self.bus.lines_idle() {
                    Ok(c)
                } else {
                    Err(ClearError::SdaHeldLow)
                }
            }) {
                self.stats.errors += 1;
                return Err(GuardError::Stuck(e));
            }
        }
        match f(&mut self.bus) {
            Ok(v) => {
                self.errors_in_row = 0;
                self.stuck = false;
                Ok(v)
            }
            Err(e) => {
                self.stats.errors += 1;
                self.errors_in_row = self.errors_in_row.saturating_add(1);
                if self.errors_in_row >= Self::ERRORS_BEFORE_RECOVERY || self.bus.needs_clear(&e) {
                    // Whatever the outcome, this transfer failed; the clear is for the
                    // next one.
                    let _ = self.clear();
                }
                Err(GuardError::Bus(e))
            }
        }
    }
}

impl<B: Recoverable> ErrorType for Guarded<B> {
    type Error = GuardError<B::Error>;
}

impl<B: Recoverable> I2c<SevenBitAddress> for Guarded<B> {
    fn read(&mut self, address: u8, read: &mut [u8]) -> Result<(), Self::Error> {
        self.guarded(|b| b.read(address, read))
    }

    fn write(&mut self, address: u8, write: &[u8]) -> Result<(), Self::Error> {
        self.guarded(|b| b.write(address, write))
    }

    fn write_read(
        &mut self,
        address: u8,
        write: &[u8],
        read: &mut [u8],
    ) -> Result<(), Self::Error> {
        self.guarded(|b| b.write_read(address, write, read))
    }

    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        self.guarded(|b| b.transaction(address, operations))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::delay::NoopDelay;
    use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction as Pin};
    use embedded_hal_mock::eh1::i2c::{Mock as I2cMock, Transaction as I2cT};

    /// The pin transactions of one SCL pulse that the slave does not stretch.
    fn pulse() -> [Pin; 3] {
        [
            Pin::set(State::Low),
            Pin::set(State::High),
            Pin::get(State::High),
        ]
    }

    /// The SCL side of a STOP (low, high, read back high).
    fn scl_stop() -> [Pin; 3] {
        pulse()
    }

    fn scl_script(pulses: usize) -> Vec<Pin> {
        let mut v = vec![Pin::set(State::High), Pin::get(State::High)];
        for _ in 0..pulses {
            v.extend(pulse());
        }
        v.extend(scl_stop());
        v
    }

    /// SDA: released, read low `held` times (then high), STOP (low, high), read back.
    fn sda_script(held: usize, end: State) -> Vec<Pin> {
        let mut v = vec![Pin::set(State::High)];
        for _ in 0..held {
            v.push(Pin::get(State::Low));
        }
        if held < 9 {
            v.push(Pin::get(State::High));
        }
        v.extend([Pin::set(State::Low), Pin::set(State::High), Pin::get(end)]);
        v
    }

    #[test]
    fn a_free_bus_gets_only_a_stop() {
        let mut scl = PinMock::new(&scl_script(0));
        let mut sda = PinMock::new(&sda_script(0, State::High));
        assert_eq!(
            clear_bus(&mut scl, &mut sda, &mut NoopDelay),
            Ok(Cleared { pulses: 0 })
        );
        scl.done();
        sda.done();
    }

    #[test]
    fn a_slave_holding_sda_is_clocked_free_then_stopped() {
        // The slave had 3 bits of a byte left to send: SDA low for 3 pulses.
        let mut scl = PinMock::new(&scl_script(3));
        let mut sda = PinMock::new(&sda_script(3, State::High));
        assert_eq!(
            clear_bus(&mut scl, &mut sda, &mut NoopDelay),
            Ok(Cleared { pulses: 3 })
        );
        scl.done();
        sda.done();
    }

    #[test]
    fn at_most_nine_pulses_then_the_failure_is_reported() {
        let mut scl = PinMock::new(&scl_script(9));
        let mut sda = PinMock::new(&sda_script(9, State::Low));
        assert_eq!(
            clear_bus(&mut scl, &mut sda, &mut NoopDelay),
            Err(ClearError::SdaHeldLow)
        );
        scl.done();
        sda.done();
    }

    #[test]
    fn a_clock_held_low_for_good_is_reported_without_clocking() {
        let mut s = vec![Pin::set(State::High)];
        s.extend((0..STRETCH_LIMIT).map(|_| Pin::get(State::Low)));
        let mut scl = PinMock::new(&s);
        let mut sda = PinMock::new(&[Pin::set(State::High)]);
        assert_eq!(
            clear_bus(&mut scl, &mut sda, &mut NoopDelay),
            Err(ClearError::SclHeldLow)
        );
        scl.done();
        sda.done();
    }

    #[test]
    fn a_short_stretch_is_waited_for() {
        let mut s = vec![Pin::set(State::High), Pin::get(State::High)];
        // The pulse's rising edge is stretched for two reads.
        s.extend([
            Pin::set(State::Low),
            Pin::set(State::High),
            Pin::get(State::Low),
            Pin::get(State::Low),
            Pin::get(State::High),
        ]);
        s.extend(scl_stop());
        let mut scl = PinMock::new(&s);
        let mut sda = PinMock::new(&sda_script(1, State::High));
        assert_eq!(
            clear_bus(&mut scl, &mut sda, &mut NoopDelay),
            Ok(Cleared { pulses: 1 })
        );
        scl.done();
        sda.done();
    }

    /// A bus for the guard's tests: an I2C mock, mock SCL/SDA pins and a script of line
    /// levels ("idle" answers) — the board's version takes the pins from the peripheral.
    struct MockBus {
        i2c: I2cMock,
        scl: PinMock,
        sda: PinMock,
        idle: Vec<bool>,
    }

    impl ErrorType for MockBus {
        type Error = ErrorKind;
    }

    impl I2c for MockBus {
        fn read(&mut self, a: u8, r: &mut [u8]) -> Result<(), ErrorKind> {
            self.i2c.read(a, r)
        }
        fn write(&mut self, a: u8, w: &[u8]) -> Result<(), ErrorKind> {
            self.i2c.write(a, w)
        }
        fn write_read(&mut self, a: u8, w: &[u8], r: &mut [u8]) -> Result<(), ErrorKind> {
            self.i2c.write_read(a, w, r)
        }
        fn transaction(&mut self, a: u8, o: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
            self.i2c.transaction(a, o)
        }
    }

    impl Recoverable for MockBus {
        fn lines_idle(&mut self) -> bool {
            self.idle.remove(0)
        }
        fn clear_and_reinit(&mut self) -> Result<Cleared, ClearError> {
            clear_bus(&mut self.scl, &mut self.sda, &mut NoopDelay)
        }
    }

    impl MockBus {
        fn done(mut self) {
            self.i2c.done();
            self.scl.done();
            self.sda.done();
            assert!(self.idle.is_empty(), "unused idle answers");
        }
    }

    #[test]
    fn a_stuck_bus_is_cleared_before_the_transfer_and_the_devices_flagged() {
        let mut g = Guarded::new(MockBus {
            i2c: I2cMock::new(&[I2cT::write_read(0x68, vec![0x00], vec![0xD1])]),
            scl: PinMock::new(&scl_script(2)),
            sda: PinMock::new(&sda_script(2, State::High)),
            idle: vec![false, true],
        });
        let mut id = [0u8];
        assert_eq!(g.write_read(0x68, &[0x00], &mut id), Ok(()));
        assert_eq!(id, [0xD1]);
        assert_eq!(
            g.stats(),
            BusStats {
                errors: 0,
                stuck: 1,
                recoveries: 1,
                failed_recoveries: 0
            }
        );
        assert_eq!(g.last_clear(), Some(Ok(Cleared { pulses: 2 })));
        assert!(!g.stuck());
        assert!(g.take_reinit());
        assert!(!g.take_reinit(), "the flag is taken once");
        g.bus.done();
    }

    #[test]
    fn a_bus_that_stays_stuck_sends_nothing_and_says_so() {
        let mut g = Guarded::new(MockBus {
            i2c: I2cMock::new(&[]),
            scl: PinMock::new(&scl_script(9)),
            sda: PinMock::new(&sda_script(9, State::Low)),
            idle: vec![false],
        });
        assert_eq!(
            g.write(0x3C, &[0x00, 0xAF]),
            Err(GuardError::Stuck(ClearError::SdaHeldLow))
        );
        assert_eq!(
            i2c::Error::kind(&GuardError::<ErrorKind>::Stuck(ClearError::SdaHeldLow)),
            ErrorKind::Bus
        );
        let s = g.stats();
        assert_eq!(
            (s.errors, s.stuck, s.recoveries, s.failed_recoveries),
            (1, 1, 0, 1)
        );
        assert!(g.stuck(), "a failed clear leaves the bus stuck");
        g.bus.done();
    }

    #[test]
    fn a_stuck_bus_is_stuck_until_a_transfer_succeeds() {
        let mut g = Guarded::new(MockBus {
            i2c: I2cMock::new(&[I2cT::write(0x3C, vec![0x00, 0xAF])]),
            scl: PinMock::new(&scl_script(9)),
            sda: PinMock::new(&sda_script(9, State::Low)),
            idle: vec![false, true],
        });
        assert!(g.write(0x3C, &[0x00, 0xAF]).is_err());
        assert!(g.stuck());
        // The slave let go by itself: the next transfer finds the lines idle.
        assert_eq!(g.write(0x3C, &[0x00, 0xAF]), Ok(()));
        assert!(!g.stuck());
        g.bus.done();
    }

    #[test]
    fn repeated_failures_clear_the_bus_and_a_success_resets_the_count() {
        let nack = ErrorKind::NoAcknowledge(i2c::NoAcknowledgeSource::Address);
        let mut g = Guarded::new(MockBus {
            i2c: I2cMock::new(&[
                I2cT::write(0x1E, vec![0x60]).with_error(nack),
                I2cT::write(0x1E, vec![0x60]).with_error(nack),
                I2cT::write(0x1E, vec![0x60]),
                I2cT::write(0x1E, vec![0x60]).with_error(nack),
                I2cT::write(0x1E, vec![0x60]).with_error(nack),
                I2cT::write(0x1E, vec![0x60]).with_error(nack),
                I2cT::write(0x1E, vec![0x60]),
            ]),
            scl: PinMock::new(&scl_script(0)),
            sda: PinMock::new(&sda_script(0, State::High)),
            idle: vec![true; 7],
        });
        let results: Vec<bool> = (0..7).map(|_| g.write(0x1E, &[0x60]).is_ok()).collect();
        assert_eq!(results, [false, false, true, false, false, false, true]);
        // Two errors, a success (count reset), three errors: one clear, after the third.
        let s = g.stats();
        assert_eq!(
            (s.errors, s.stuck, s.recoveries, s.failed_recoveries),
            (5, 0, 1, 0)
        );
        assert!(g.take_reinit());
        g.bus.done();
    }
}
