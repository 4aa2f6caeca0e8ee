//! SPI framing of the ADS131M04: word packing, the output CRC, one full-duplex frame.
//!
//! Every SPI frame is 6 words (command/response, channels 0–3, CRC) of 16, 24 or 32 bits,
//! MSB first, in SPI mode 1 (CPOL 0, CPHA 1). A command is 16 bits placed in the upper
//! bits of the first word, the rest of the word zero. The device answers a command in
//! the *next* frame, so each driver operation that needs an answer clocks two frames.
//! The output CRC (CRC-16-CCITT, polynomial 0x1021, seed 0xFFFF) covers every byte of the
//! frame before the CRC word, padding included; the CRC itself is the upper 16 bits of
//! the last word. Input CRC (`MODE.RX_CRC_EN`) stays off, its reset default.

use super::types::WordLength;
use embedded_hal::spi::SpiDevice;

/// Words in one frame of the 4-channel device: response, 4 channels, CRC.
pub(crate) const WORDS_PER_FRAME: usize = 6;
/// Largest frame in bytes (32-bit words).
pub(crate) const MAX_FRAME_BYTES: usize = WORDS_PER_FRAME * 4;

/// CRC-16-CCITT (poly 0x1021, seed 0xFFFF, no reflection, no final xor) of `bytes`.
pub fn crc16_ccitt(bytes: &[u8]) -> u16 {
    bytes.iter().fold(0xFFFF_u16, |mut crc, &b| {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
        crc
    })
}

/// A received frame: raw bytes and the word length they were clocked with.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RawFrame {
    bytes: [u8; MAX_FRAME_BYTES],
    wl: WordLength,
}

impl RawFrame {
    fn word(&self, i: usize) -> &[u8] {
        let w = self.wl.bytes();
        self.bytes.get(i * w..(i + 1) * w).unwrap_or(&[])
    }

    /// The upper 16 bits of word `i` (command answers and the CRC).
    pub(crate) fn word16(&self, i: usize) -> u16 {
        let w = self.word(i);
        match (w.first(), w.get(1)) {
            (Some(&hi), Some(&lo)) => u16::from_be_bytes([hi, lo]),
            _ => 0,
        }
    }

    /// Conversion result of channel `ch` (0–3) in 24-bit units, and whether it is clipped.
    pub(crate) fn sample(&self, ch: usize) -> (i32, bool) {
        let w = self.word(1 + ch);
        let b = |k: usize| w.get(k).copied().unwrap_or(0);
        match self.wl {
            WordLength::Bits16 => {
                let v = i16::from_be_bytes([b(0), b(1)]);
                (i32::from(v) << 8, v == i16::MAX || v == i16::MIN)
            }
            WordLength::Bits24 | WordLength::Bits32ZeroPad => {
                // Sign-extend the 24-bit value by placing it in the top of an i32.
                let v = i32::from_be_bytes([b(0), b(1), b(2), 0]) >> 8;
                (v, v == 0x7F_FFFF || v == -0x80_0000)
            }
            WordLength::Bits32SignExtend => {
                let v = i32::from_be_bytes([b(0), b(1), b(2), b(3)]);
                (v, v == 0x7F_FFFF || v == -0x80_0000)
            }
        }
    }

    /// Whether the received CRC matches the bytes before it.
    pub(crate) fn crc_ok(&self) -> bool {
        let n = (WORDS_PER_FRAME - 1) * self.wl.bytes();
        let computed = crc16_ccitt(self.bytes.get(..n).unwrap_or(&[]));
        computed == self.word16(WORDS_PER_FRAME - 1)
    }
}

/// Lay out `words` (16-bit commands/register values) as a full frame in `wl`.
pub(crate) fn encode_frame(wl: WordLength, words: &[u16]) -> ([u8; MAX_FRAME_BYTES], usize) {
    let w = wl.bytes();
    let mut buf = [0u8; MAX_FRAME_BYTES];
    for (chunk, word) in buf
        .chunks_exact_mut(w)
        .zip(words.iter().take(WORDS_PER_FRAME))
    {
        let [hi, lo] = word.to_be_bytes();
        if let [a, b, ..] = chunk {
            *a = hi;
            *b = lo;
        }
    }
    (buf, WORDS_PER_FRAME * w)
}

/// Clock one full-duplex frame: send `words` (zero-padded to 6 words), return what came back.
pub(crate) fn transfer_frame<SPI: SpiDevice>(
    spi: &mut SPI,
    wl: WordLength,
    words: &[u16],
) -> Result<RawFrame, SPI::Error> {
    let (mut bytes, n) = encode_frame(wl, words);
    if let Some(buf) = bytes.get_mut(..n) {
        spi.transfer_in_place(buf)?;
    }
    Ok(RawFrame { bytes, wl })
}
