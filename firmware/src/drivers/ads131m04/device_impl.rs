//! The driver's operations.

use super::interface::{RawFrame, transfer_frame};
use super::register::{Register, clock, command, mode};
use super::types::{Channel, Channels, Config, Frame, Gain, Osr, PowerMode, Status, WordLength};
use super::{Ads131m04, Error};
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::InputPin;
use embedded_hal::spi::SpiDevice;

/// Default number of DRDY reads before [`Ads131m04::wait_data_ready`] gives up. At
/// 8 kSPS a sample is due every 125 µs; a few thousand GPIO reads cover that many times
/// over on a 168 MHz M4F.
pub const DEFAULT_DRDY_POLL_LIMIT: u32 = 10_000;

/// Expected upper byte of the ID register (`0x24xx`: 4 channels).
const ID_UPPER: u16 = 0x2400;

type Res<T, SPI, DRDY> = Result<
    T,
    Error<
        <SPI as embedded_hal::spi::ErrorType>::Error,
        <DRDY as embedded_hal::digital::ErrorType>::Error,
    >,
>;

impl<SPI, DRDY> Ads131m04<SPI, DRDY>
where
    SPI: SpiDevice,
    DRDY: InputPin,
{
    /// Wrap the SPI device and DRDY pin; assumes the device is in its reset state
    /// (24-bit words). Nothing is sent.
    pub fn new(spi: SPI, drdy: DRDY) -> Self {
        Ads131m04 {
            spi,
            drdy,
            word_length: WordLength::Bits24,
            mode: mode::RESET_VALUE,
            clock: clock::RESET_VALUE,
            gain: 0,
            drdy_poll_limit: DEFAULT_DRDY_POLL_LIMIT,
        }
    }

    /// Give back the SPI device and the DRDY pin.
    pub fn destroy(self) -> (SPI, DRDY) {
        (self.spi, self.drdy)
    }

    /// Set how many DRDY reads [`Self::wait_data_ready`] makes before returning
    /// [`Error::Timeout`] (at least 1).
    pub fn set_drdy_poll_limit(&mut self, polls: u32) {
        self.drdy_poll_limit = polls.max(1);
    }

    /// The word length the driver is currently framing with.
    pub fn word_length(&self) -> WordLength {
        self.word_length
    }

    fn frame(&mut self, words: &[u16]) -> Res<RawFrame, SPI, DRDY> {
        transfer_frame(&mut self.spi, self.word_length, words).map_err(Error::Comm)
    }

    /// Clock a NULL frame and return its CRC-checked contents: it carries the answer to
    /// the previous command.
    fn answer(&mut self) -> Res<RawFrame, SPI, DRDY> {
        let f = self.frame(&[command::NULL])?;
        if f.crc_ok() { Ok(f) } else { Err(Error::Crc) }
    }

    /// Send a one-word command, then check that the next frame echoes `expected`.
    fn command(&mut self, cmd: u16, expected: u16) -> Res<(), SPI, DRDY> {
        self.frame(&[cmd])?;
        let got = self.answer()?.word16(0);
        if got == expected {
            Ok(())
        } else {
            Err(Error::UnexpectedResponse(got))
        }
    }

    /// Software reset: sends RESET, waits 10 µs, checks the 0xFF24 acknowledgement and
    /// returns the shadow registers to their reset values (24-bit words).
    pub fn reset<D: DelayNs>(&mut self, delay: &mut D) -> Res<(), SPI, DRDY> {
        self.frame(&[command::RESET])?;
        // The register map is ready t_REGACQ (5 µs) after reset.
        delay.delay_us(10);
        self.word_length = WordLength::Bits24;
        self.mode = mode::RESET_VALUE;
        self.clock = clock::RESET_VALUE;
        self.gain = 0;
        let got = self.answer()?.word16(0);
        if got == command::RESET_ACK {
            Ok(())
        } else {
            Err(Error::UnexpectedResponse(got))
        }
    }

    /// Read one register (two frames: RREG, then NULL whose first word is the value).
    /// The conversion data clocked out meanwhile are discarded.
    pub fn read_register(&mut self, reg: Register) -> Res<u16, SPI, DRDY> {
        self.frame(&[command::rreg(reg.addr(), 0)])?;
        Ok(self.answer()?.word16(0))
    }

    /// Write one register and check the WREG acknowledgement (two frames).
    ///
    /// Writing `MODE` may change the word length: the driver switches framing for the
    /// acknowledgement frame, as the device does.
    pub fn write_register(&mut self, reg: Register, value: u16) -> Res<(), SPI, DRDY> {
        self.frame(&[command::wreg(reg.addr(), 0), value])?;
        if reg == Register::MODE {
            self.word_length = WordLength::from_bits(value >> mode::WLENGTH_SHIFT);
            self.mode = value;
        }
        let got = self.answer()?.word16(0);
        if got != command::wreg_ack(reg.addr(), 0) {
            return Err(Error::UnexpectedResponse(got));
        }
        if reg == Register::CLOCK {
            self.clock = value;
        } else if reg == Register::GAIN1 {
            self.gain = value;
        }
        Ok(())
    }

    /// The ID register (0x24xx on an ADS131M04).
    pub fn id(&mut self) -> Res<u16, SPI, DRDY> {
        self.read_register(Register::ID)
    }

    /// Read the ID and fail with [`Error::UnexpectedId`] unless it is an ADS131M04's.
    pub fn check_id(&mut self) -> Res<u16, SPI, DRDY> {
        let id = self.id()?;
        if id & 0xFF00 == ID_UPPER {
            Ok(id)
        } else {
            Err(Error::UnexpectedId(id))
        }
    }

    /// The STATUS register.
    pub fn status(&mut self) -> Res<Status, SPI, DRDY> {
        self.read_register(Register::STATUS).map(Status)
    }

    /// Apply a whole [`Config`]: MODE (word length; also clears the reset flag), CLOCK
    /// and GAIN1. Turbo OSR outside high-resolution mode is [`Error::InvalidInput`].
    pub fn configure(&mut self, cfg: &Config) -> Res<(), SPI, DRDY> {
        if cfg.osr == Osr::Osr64Turbo && cfg.power != PowerMode::HighResolution {
            return Err(Error::InvalidInput);
        }
        let mode = (self.mode & !(mode::RESET | (mode::WLENGTH_MASK << mode::WLENGTH_SHIFT)))
            | ((cfg.word_length as u16) << mode::WLENGTH_SHIFT);
        self.write_register(Register::MODE, mode)?;
        self.write_register(Register::CLOCK, cfg.clock_bits())?;
        self.write_register(Register::GAIN1, cfg.gain_bits())
    }

    /// Change the oversampling ratio and power mode, keeping the channel enables.
    pub fn set_osr(&mut self, osr: Osr, power: PowerMode) -> Res<(), SPI, DRDY> {
        let mut cfg = self.shadow_config();
        cfg.osr = osr;
        cfg.power = power;
        if osr == Osr::Osr64Turbo && power != PowerMode::HighResolution {
            return Err(Error::InvalidInput);
        }
        self.write_register(Register::CLOCK, cfg.clock_bits())
    }

    /// Enable exactly `channels` (the others are powered down and read 0).
    pub fn set_channels(&mut self, channels: Channels) -> Res<(), SPI, DRDY> {
        let v = (self.clock & !(0x0F << clock::CH_EN_SHIFT))
            | ((channels.bits() as u16) << clock::CH_EN_SHIFT);
        self.write_register(Register::CLOCK, v)
    }

    /// Set the PGA gain of one channel.
    pub fn set_gain(&mut self, ch: Channel, gain: Gain) -> Res<(), SPI, DRDY> {
        let shift = 4 * ch as u16;
        let v = (self.gain & !(0b111 << shift)) | ((gain as u16) << shift);
        self.write_register(Register::GAIN1, v)
    }

    /// Set the PGA gain of the three coil channels (0–2) at once, keeping channel 3's:
    /// one `GAIN1` write, so the coils never run at different gains (their relative
    /// amplitudes are the field's direction). Used by the gain ranging
    /// ([`crate::frontend::RangeChange`]).
    pub fn set_coil_gains(&mut self, gain: Gain) -> Res<(), SPI, DRDY> {
        let g = gain as u16;
        let v = (self.gain & 0xF000) | g | (g << 4) | (g << 8);
        self.write_register(Register::GAIN1, v)
    }

    /// Change the SPI word length (takes effect from the next frame).
    pub fn set_word_length(&mut self, wl: WordLength) -> Res<(), SPI, DRDY> {
        let v = (self.mode & !(mode::WLENGTH_MASK << mode::WLENGTH_SHIFT))
            | ((wl as u16) << mode::WLENGTH_SHIFT);
        self.write_register(Register::MODE, v)
    }

    /// The PGA gain of `ch` as last written.
    pub fn gain(&self, ch: Channel) -> Gain {
        Gain::from_bits(self.gain >> (4 * ch as u16))
    }

    fn shadow_config(&self) -> Config {
        let c = self.clock;
        let osr = if c & clock::TBM != 0 {
            Osr::Osr64Turbo
        } else {
            match (c >> clock::OSR_SHIFT) & 0b111 {
                0 => Osr::Osr128,
                1 => Osr::Osr256,
                2 => Osr::Osr512,
                3 => Osr::Osr1024,
                4 => Osr::Osr2048,
                5 => Osr::Osr4096,
                6 => Osr::Osr8192,
                _ => Osr::Osr16256,
            }
        };
        let power = match c & clock::PWR_MASK {
            0 => PowerMode::VeryLowPower,
            1 => PowerMode::LowPower,
            _ => PowerMode::HighResolution,
        };
        Config {
            osr,
            power,
            channels: Channels::from_bits((c >> clock::CH_EN_SHIFT) as u8),
            gains: Channel::ALL.map(|ch| self.gain(ch)),
            word_length: self.word_length,
        }
    }

    /// The configuration as last written (from the shadow registers).
    pub fn config(&self) -> Config {
        self.shadow_config()
    }

    /// Poll DRDY until it is low (data ready), at most the poll limit times; then
    /// [`Error::Timeout`].
    pub fn wait_data_ready(&mut self) -> Res<(), SPI, DRDY> {
        for _ in 0..self.drdy_poll_limit {
            if self.drdy.is_low().map_err(Error::Pin)? {
                return Ok(());
            }
        }
        Err(Error::Timeout)
    }

    /// Read one frame (NULL command): STATUS, the 4 conversion results with saturation
    /// flags. A CRC mismatch is [`Error::Crc`]. Does not wait for DRDY.
    pub fn read_frame(&mut self) -> Res<Frame, SPI, DRDY> {
        let f = self.answer()?;
        let mut raw = [0i32; 4];
        let mut saturated = Channels::NONE;
        for (ch, r) in Channel::ALL.iter().zip(raw.iter_mut()) {
            let (v, sat) = f.sample(*ch as usize);
            *r = v;
            if sat {
                saturated = saturated.with(*ch);
            }
        }
        Ok(Frame {
            status: Status(f.word16(0)),
            raw,
            saturated,
        })
    }

    /// [`Self::wait_data_ready`], then [`Self::read_frame`].
    pub fn read_frame_when_ready(&mut self) -> Res<Frame, SPI, DRDY> {
        self.wait_data_ready()?;
        self.read_frame()
    }

    /// Convert a frame to volts at the ADC input: `code / 2²³ × 1.2 V / gain`.
    pub fn to_volts(&self, frame: &Frame) -> [f32; 4] {
        let mut v = [0.0f32; 4];
        for ((out, raw), ch) in v.iter_mut().zip(frame.raw.iter()).zip(Channel::ALL) {
            *out = *raw as f32 * (self.gain(ch).full_scale_v() / 8_388_608.0);
        }
        v
    }

    /// Enter standby (modulators off, registers kept), checking the acknowledgement.
    pub fn standby(&mut self) -> Res<(), SPI, DRDY> {
        self.command(command::STANDBY, command::STANDBY)
    }

    /// Leave standby, checking the acknowledgement.
    pub fn wakeup(&mut self) -> Res<(), SPI, DRDY> {
        self.command(command::WAKEUP, command::WAKEUP)
    }

    /// Lock the interface against register writes, checking the acknowledgement.
    pub fn lock(&mut self) -> Res<(), SPI, DRDY> {
        self.command(command::LOCK, command::LOCK)
    }

    /// Unlock the interface, checking the acknowledgement.
    pub fn unlock(&mut self) -> Res<(), SPI, DRDY> {
        self.command(command::UNLOCK, command::UNLOCK)
    }
}
