//! Configuration and data types of the ADS131M04 driver.

use super::register::{clock, status};

/// One of the four input channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Channel {
    /// Channel 0 (antenna coil x).
    Ch0 = 0,
    /// Channel 1 (antenna coil y).
    Ch1 = 1,
    /// Channel 2 (antenna coil z).
    Ch2 = 2,
    /// Channel 3 (spare).
    Ch3 = 3,
}

impl Channel {
    /// All channels, in order.
    pub const ALL: [Channel; 4] = [Channel::Ch0, Channel::Ch1, Channel::Ch2, Channel::Ch3];
}

/// A set of channels as a 4-bit mask (bit n = channel n).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Channels(u8);

impl Channels {
    /// No channel.
    pub const NONE: Channels = Channels(0);
    /// All four channels.
    pub const ALL: Channels = Channels(0x0F);
    /// Channels 0–2: the three antenna coils.
    pub const COILS: Channels = Channels(0x07);

    /// The set holding exactly the channels whose bits are set in `mask` (bits above 3 ignored).
    pub const fn from_bits(mask: u8) -> Channels {
        Channels(mask & 0x0F)
    }
    /// The 4-bit mask.
    pub const fn bits(self) -> u8 {
        self.0
    }
    /// This set plus `ch`.
    pub const fn with(self, ch: Channel) -> Channels {
        Channels(self.0 | (1 << ch as u8))
    }
    /// Whether `ch` is in the set.
    pub const fn contains(self, ch: Channel) -> bool {
        self.0 & (1 << ch as u8) != 0
    }
    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
}

/// Programmable-gain-amplifier setting; full scale is ±1.2 V / gain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Gain {
    /// ×1 (±1.2 V).
    #[default]
    G1 = 0,
    /// ×2 (±600 mV).
    G2 = 1,
    /// ×4 (±300 mV).
    G4 = 2,
    /// ×8 (±150 mV).
    G8 = 3,
    /// ×16 (±75 mV).
    G16 = 4,
    /// ×32 (±37.5 mV).
    G32 = 5,
    /// ×64 (±18.75 mV).
    G64 = 6,
    /// ×128 (±9.375 mV).
    G128 = 7,
}

impl Gain {
    /// The gain as a number (1 … 128).
    pub const fn factor(self) -> u16 {
        1 << self as u16
    }
    /// Full-scale input (V): the input that reads as code ±2²³.
    pub fn full_scale_v(self) -> f32 {
        1.2 / self.factor() as f32
    }
    pub(crate) const fn from_bits(bits: u16) -> Gain {
        match bits & 0b111 {
            0 => Gain::G1,
            1 => Gain::G2,
            2 => Gain::G4,
            3 => Gain::G8,
            4 => Gain::G16,
            5 => Gain::G32,
            6 => Gain::G64,
            _ => Gain::G128,
        }
    }
}

/// Oversampling ratio of the sinc³ decimation filter; data rate = f_MOD / OSR with
/// f_MOD = f_CLKIN / 2 (4.096 MHz from the nominal 8.192 MHz clock in high-resolution mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Osr {
    /// OSR 64 (turbo mode, high-resolution power mode only): 64 kSPS.
    Osr64Turbo,
    /// OSR 128: 32 kSPS.
    Osr128,
    /// OSR 256: 16 kSPS.
    Osr256,
    /// OSR 512: 8 kSPS, the receiver's setting (IF 2 kHz = f_DATA / 4).
    Osr512,
    /// OSR 1024: 4 kSPS (reset default).
    Osr1024,
    /// OSR 2048: 2 kSPS.
    Osr2048,
    /// OSR 4096: 1 kSPS.
    Osr4096,
    /// OSR 8192: 500 SPS.
    Osr8192,
    /// OSR 16256: ≈252 SPS.
    Osr16256,
}

impl Osr {
    /// The oversampling ratio as a number.
    pub const fn ratio(self) -> u32 {
        match self {
            Osr::Osr64Turbo => 64,
            Osr::Osr128 => 128,
            Osr::Osr256 => 256,
            Osr::Osr512 => 512,
            Osr::Osr1024 => 1024,
            Osr::Osr2048 => 2048,
            Osr::Osr4096 => 4096,
            Osr::Osr8192 => 8192,
            Osr::Osr16256 => 16256,
        }
    }
    /// `(OSR[2:0], TBM)` field values.
    pub(crate) const fn bits(self) -> (u16, bool) {
        match self {
            Osr::Osr64Turbo => (0, true),
            Osr::Osr128 => (0, false),
            Osr::Osr256 => (1, false),
            Osr::Osr512 => (2, false),
            Osr::Osr1024 => (3, false),
            Osr::Osr2048 => (4, false),
            Osr::Osr4096 => (5, false),
            Osr::Osr8192 => (6, false),
            Osr::Osr16256 => (7, false),
        }
    }
}

/// Power mode (`CLOCK.PWR`); each expects its own f_CLKIN (8.192 / 4.096 / 2.048 MHz).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PowerMode {
    /// Very-low-power (f_CLKIN 2.048 MHz).
    VeryLowPower = 0,
    /// Low-power (f_CLKIN 4.096 MHz).
    LowPower = 1,
    /// High-resolution (f_CLKIN 8.192 MHz), the reset default.
    HighResolution = 2,
}

/// SPI word length (`MODE.WLENGTH`); a frame is always 6 words.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum WordLength {
    /// 16-bit words: conversion data truncated to their 16 MSBs.
    Bits16 = 0,
    /// 24-bit words (reset default).
    #[default]
    Bits24 = 1,
    /// 32-bit words, data in the upper 24 bits and zero padding below.
    Bits32ZeroPad = 2,
    /// 32-bit words, conversion data sign-extended into the upper byte.
    Bits32SignExtend = 3,
}

impl WordLength {
    /// Bytes per word.
    pub const fn bytes(self) -> usize {
        match self {
            WordLength::Bits16 => 2,
            WordLength::Bits24 => 3,
            WordLength::Bits32ZeroPad | WordLength::Bits32SignExtend => 4,
        }
    }
    pub(crate) const fn from_bits(bits: u16) -> WordLength {
        match bits & 0b11 {
            0 => WordLength::Bits16,
            1 => WordLength::Bits24,
            2 => WordLength::Bits32ZeroPad,
            _ => WordLength::Bits32SignExtend,
        }
    }
}

/// Everything [`Ads131m04::configure`](super::Ads131m04::configure) writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Config {
    /// Oversampling ratio (sets the data rate).
    pub osr: Osr,
    /// Power mode.
    pub power: PowerMode,
    /// Enabled channels; disabled channels read as 0.
    pub channels: Channels,
    /// PGA gain per channel.
    pub gains: [Gain; 4],
    /// SPI word length.
    pub word_length: WordLength,
}

impl Default for Config {
    /// The receiver's setting: 8 kSPS (OSR 512 at 8.192 MHz), high resolution, all
    /// channels on, gain 1, 24-bit words.
    fn default() -> Self {
        Config {
            osr: Osr::Osr512,
            power: PowerMode::HighResolution,
            channels: Channels::ALL,
            gains: [Gain::G1; 4],
            word_length: WordLength::Bits24,
        }
    }
}

impl Config {
    /// The `CLOCK` register value of this configuration.
    pub(crate) fn clock_bits(&self) -> u16 {
        let (osr, turbo) = self.osr.bits();
        let mut v = ((self.channels.bits() as u16) << clock::CH_EN_SHIFT)
            | (osr << clock::OSR_SHIFT)
            | (self.power as u16 & clock::PWR_MASK);
        if turbo {
            v |= clock::TBM;
        }
        v
    }
    /// The `GAIN1` register value of this configuration.
    pub(crate) fn gain_bits(&self) -> u16 {
        self.gains
            .iter()
            .enumerate()
            .fold(0, |acc, (i, g)| acc | ((*g as u16) << (4 * i)))
    }
    /// Output data rate (samples/s per channel) for a clock of `f_clkin_hz`.
    pub fn data_rate_hz(&self, f_clkin_hz: f32) -> f32 {
        f_clkin_hz / 2.0 / self.osr.ratio() as f32
    }
}

/// The STATUS word (answer to NULL, and register 0x01).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Status(pub u16);

impl Status {
    /// Whether channel `ch` has new data (`DRDYn`).
    pub const fn data_ready(self, ch: Channel) -> bool {
        self.0 & (1 << ch as u16) != 0
    }
    /// Whether the interface is locked.
    pub const fn locked(self) -> bool {
        self.0 & status::LOCK != 0
    }
    /// Whether the ADC was resynchronised (this frame's data may be invalid).
    pub const fn resynced(self) -> bool {
        self.0 & status::F_RESYNC != 0
    }
    /// Whether the register-map CRC changed.
    pub const fn register_map_changed(self) -> bool {
        self.0 & status::REG_MAP != 0
    }
    /// Whether the device saw a CRC error on its input (input CRC enabled only).
    pub const fn input_crc_error(self) -> bool {
        self.0 & status::CRC_ERR != 0
    }
    /// Whether a reset happened since `MODE.RESET` was last cleared.
    pub const fn reset_occurred(self) -> bool {
        self.0 & status::RESET != 0
    }
    /// Word length the device is using.
    pub const fn word_length(self) -> WordLength {
        WordLength::from_bits(self.0 >> status::WLENGTH_SHIFT)
    }
}

/// One conversion of all four channels, as read by
/// [`Ads131m04::read_frame`](super::Ads131m04::read_frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// The STATUS word that headed the frame.
    pub status: Status,
    /// Conversion results in 24-bit two's-complement units (±2²³ = full scale); in
    /// 16-bit word mode the 16 received bits are shifted up by 8.
    pub raw: [i32; 4],
    /// Channels whose code sits at positive or negative full scale (clipped input).
    pub saturated: Channels,
}

impl Frame {
    /// Whether any of the three coil channels (0–2) is clipped.
    pub fn coils_saturated(&self) -> bool {
        self.saturated.bits() & Channels::COILS.bits() != 0
    }
}
