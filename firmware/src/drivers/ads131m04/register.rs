//! Register map, command words and bit fields of the ADS131M04 (TI SBAS946).
//!
//! Only what the driver uses is named here; [`Register`] still reaches every address so
//! that [`Ads131m04::read_register`](super::Ads131m04::read_register) can read any of
//! them for diagnostics.

use super::types::Channel;

/// A register address (6 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Register(u8);

impl Register {
    /// `ID`: device identification, read-only; upper byte 0x24 on the ADS131M04.
    pub const ID: Register = Register(0x00);
    /// `STATUS`: device status, read-only (the same word answers a NULL command).
    pub const STATUS: Register = Register(0x01);
    /// `MODE`: word length, CRC options, DRDY behaviour, reset flag.
    pub const MODE: Register = Register(0x02);
    /// `CLOCK`: channel enables, turbo mode, oversampling ratio, power mode.
    pub const CLOCK: Register = Register(0x03);
    /// `GAIN1`: PGA gain of channels 0–3.
    pub const GAIN1: Register = Register(0x04);
    /// `CFG`: global-chop and current-detect configuration.
    pub const CFG: Register = Register(0x06);
    /// `THRSHLD_MSB`: current-detect threshold, upper 16 bits.
    pub const THRSHLD_MSB: Register = Register(0x07);
    /// `THRSHLD_LSB`: current-detect threshold, lower 8 bits and DC-block filter.
    pub const THRSHLD_LSB: Register = Register(0x08);
    /// `REGMAP_CRC`: CRC of the register map, read-only.
    pub const REGMAP_CRC: Register = Register(0x3E);

    /// `CHn_CFG`: phase delay, DC-block disable and input mux of channel `ch`.
    pub const fn ch_cfg(ch: Channel) -> Register {
        Register(0x09 + 5 * ch as u8)
    }
    /// `CHn_OCAL_MSB`: offset calibration of channel `ch`, upper 16 bits.
    pub const fn ch_ocal_msb(ch: Channel) -> Register {
        Register(0x0A + 5 * ch as u8)
    }
    /// `CHn_OCAL_LSB`: offset calibration of channel `ch`, lower 8 bits (in bits 15:8).
    pub const fn ch_ocal_lsb(ch: Channel) -> Register {
        Register(0x0B + 5 * ch as u8)
    }
    /// `CHn_GCAL_MSB`: gain calibration of channel `ch`, upper 16 bits.
    pub const fn ch_gcal_msb(ch: Channel) -> Register {
        Register(0x0C + 5 * ch as u8)
    }
    /// `CHn_GCAL_LSB`: gain calibration of channel `ch`, lower 8 bits (in bits 15:8).
    pub const fn ch_gcal_lsb(ch: Channel) -> Register {
        Register(0x0D + 5 * ch as u8)
    }
    /// The 6-bit address.
    pub const fn addr(self) -> u8 {
        self.0
    }
}

/// Command words (16 bits, sent MSB-aligned in the first word of a frame).
pub(crate) mod command {
    /// No operation; the answer is the STATUS word followed by conversion data.
    pub const NULL: u16 = 0x0000;
    /// Software reset.
    pub const RESET: u16 = 0x0011;
    /// Enter standby (modulators off, SPI alive).
    pub const STANDBY: u16 = 0x0022;
    /// Leave standby.
    pub const WAKEUP: u16 = 0x0033;
    /// Lock the interface: only NULL, RREG and UNLOCK are then accepted.
    pub const LOCK: u16 = 0x0555;
    /// Unlock the interface.
    pub const UNLOCK: u16 = 0x0655;
    /// Answer to RESET of a 4-channel device (0xFF20 | channel count).
    pub const RESET_ACK: u16 = 0xFF24;

    /// `RREG`: `101a_aaaa_annn_nnnn`, read `n + 1` registers from `addr`.
    pub const fn rreg(addr: u8, n_minus_1: u8) -> u16 {
        0xA000 | ((addr as u16 & 0x3F) << 7) | (n_minus_1 as u16 & 0x7F)
    }
    /// `WREG`: `011a_aaaa_annn_nnnn`, write `n + 1` registers from `addr`.
    pub const fn wreg(addr: u8, n_minus_1: u8) -> u16 {
        0x6000 | ((addr as u16 & 0x3F) << 7) | (n_minus_1 as u16 & 0x7F)
    }
    /// Answer to WREG: `010a_aaaa_ammm_mmmm`, `m + 1` registers written.
    pub const fn wreg_ack(addr: u8, n_minus_1: u8) -> u16 {
        0x4000 | ((addr as u16 & 0x3F) << 7) | (n_minus_1 as u16 & 0x7F)
    }
}

/// Bit fields of `MODE` (reset value 0x0510: 24-bit words, SPI timeout on, CCITT CRC).
pub(crate) mod mode {
    /// Reset value.
    pub const RESET_VALUE: u16 = 0x0510;
    /// `RESET` flag: set by a reset, cleared by writing 0.
    pub const RESET: u16 = 1 << 10;
    /// `WLENGTH[1:0]` shift.
    pub const WLENGTH_SHIFT: u16 = 8;
    /// `WLENGTH[1:0]` mask (after shifting).
    pub const WLENGTH_MASK: u16 = 0b11;
}

/// Bit fields of `CLOCK` (reset value 0x0F0E: all channels on, OSR 1024, high resolution).
pub(crate) mod clock {
    /// Reset value.
    pub const RESET_VALUE: u16 = 0x0F0E;
    /// `CHn_EN` bits start here (bit 8 = channel 0).
    pub const CH_EN_SHIFT: u16 = 8;
    /// Turbo mode (OSR 64).
    pub const TBM: u16 = 1 << 5;
    /// `OSR[2:0]` shift.
    pub const OSR_SHIFT: u16 = 2;
    /// `PWR[1:0]` mask.
    pub const PWR_MASK: u16 = 0b11;
}

/// Bit fields of `STATUS`.
pub(crate) mod status {
    /// Interface locked.
    pub const LOCK: u16 = 1 << 15;
    /// ADC resynchronised (data of this frame may be invalid).
    pub const F_RESYNC: u16 = 1 << 14;
    /// Register map CRC changed.
    pub const REG_MAP: u16 = 1 << 13;
    /// CRC error on the input frame (only when input CRC is enabled).
    pub const CRC_ERR: u16 = 1 << 12;
    /// A reset happened since `MODE.RESET` was last cleared.
    pub const RESET: u16 = 1 << 10;
    /// `WLENGTH[1:0]` shift.
    pub const WLENGTH_SHIFT: u16 = 8;
}
