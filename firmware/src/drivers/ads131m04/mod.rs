//! Driver for the TI ADS131M04: 4-channel, simultaneous-sampling, 24-bit ΔΣ ADC on SPI,
//! with a data-ready (DRDY, active low) pin.
//!
//! In the receiver, channels 0, 1 and 2 digitise the intermediate-frequency (IF)
//! signals of the x, y and z antenna coils (see [`crate::frontend`] for the analog
//! chain) and channel 3 is a spare. Because the four modulators sample simultaneously,
//! the coils' relative phases — which carry the field vector's relative signs — are
//! preserved.
//!
//! The driver is generic over [`SpiDevice`](embedded_hal::spi::SpiDevice) (SPI mode 1, up to 25 MHz; the device
//! handles chip select) and [`InputPin`](embedded_hal::digital::InputPin) (DRDY). No call blocks without bound and no
//! call panics: every failure is an [`Error`] value.
//!
//! Capabilities:
//! - Reset and check the reset acknowledgement: [`Ads131m04::reset`].
//! - Read the device ID, checking it is an ADS131M04: [`Ads131m04::id`],
//!   [`Ads131m04::check_id`].
//! - Configure data rate (OSR), power mode, enabled channels, PGA gains and word length
//!   in one go: [`Ads131m04::configure`] with a [`Config`]; or one at a time:
//!   [`Ads131m04::set_osr`], [`Ads131m04::set_channels`], [`Ads131m04::set_gain`],
//!   [`Ads131m04::set_word_length`].
//! - Wait for DRDY with a bounded poll: [`Ads131m04::wait_data_ready`]
//!   (limit set by [`Ads131m04::set_drdy_poll_limit`]).
//! - Read one frame of 4 channels as raw 24-bit codes with per-channel saturation flags,
//!   CRC-checked: [`Ads131m04::read_frame`], [`Ads131m04::read_frame_when_ready`];
//!   convert it to volts: [`Ads131m04::to_volts`].
//! - Read the STATUS register: [`Ads131m04::status`].
//! - Standby / wake-up, lock / unlock the interface: [`Ads131m04::standby`],
//!   [`Ads131m04::wakeup`], [`Ads131m04::lock`], [`Ads131m04::unlock`].
//! - Raw register access for what is not wrapped (phase, offset/gain calibration,
//!   global chop): [`Ads131m04::read_register`], [`Ads131m04::write_register`].
//!
//! Not supported: input CRC (`MODE.RX_CRC_EN`), multi-register RREG/WREG (the driver
//! reads and writes one register per command), current detection.
//!
//! ```
//! use firmware::drivers::ads131m04::{Ads131m04, Config};
//! # use embedded_hal_mock::eh1::{spi::Mock as Spi, digital::Mock as Pin};
//! # let spi = Spi::new(&[]);
//! # let drdy = Pin::new(&[]);
//! let mut adc = Ads131m04::new(spi, drdy);
//! // adc.reset(&mut delay)?; adc.check_id()?; adc.configure(&Config::default())?;
//! // loop { let f = adc.read_frame_when_ready()?; let v = adc.to_volts(&f); … }
//! # let (mut spi, mut drdy) = adc.destroy();
//! # spi.done(); drdy.done();
//! ```

mod device_impl;
pub mod interface;
pub mod register;
mod types;

#[cfg(test)]
mod tests;

pub use register::Register;
pub use types::{Channel, Channels, Config, Frame, Gain, Osr, PowerMode, Status, WordLength};

/// Everything that can go wrong talking to the ADC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<CommE, PinE> {
    /// The SPI bus reported an error.
    #[error("SPI error: {0:?}")]
    Comm(CommE),
    /// Reading the DRDY pin failed.
    #[error("DRDY pin read failed: {0:?}")]
    Pin(PinE),
    /// The CRC at the end of a received frame did not match its contents.
    #[error("frame CRC mismatch")]
    Crc,
    /// The ID register does not identify an ADS131M04 (the value read is attached).
    #[error("not an ADS131M04 (ID {0:#06x})")]
    UnexpectedId(u16),
    /// A command was not acknowledged as expected (the answer word is attached).
    #[error("command not acknowledged (answer {0:#06x})")]
    UnexpectedResponse(u16),
    /// DRDY did not go low within the poll limit.
    #[error("DRDY did not go low in time")]
    Timeout,
    /// An argument was out of range (e.g. turbo OSR outside high-resolution mode).
    #[error("argument out of range")]
    InvalidInput,
}

/// The ADS131M04 on an SPI device, with its DRDY pin and shadow copies of the
/// configuration registers it has written.
#[derive(Debug)]
pub struct Ads131m04<SPI, DRDY> {
    spi: SPI,
    drdy: DRDY,
    word_length: WordLength,
    mode: u16,
    clock: u16,
    gain: u16,
    drdy_poll_limit: u32,
}
