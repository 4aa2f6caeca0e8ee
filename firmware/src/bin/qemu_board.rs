//! On-target costs of the board binary's tasks that QEMU can count (instructions, with
//! `-icount shift=0`; the bus and device waits are not emulated and are modelled from the
//! wire times in `firmware::board::schedule`): the DRDY interrupt's work on one ADC frame
//! (driver frame read with CRC check over an SPI that answers at once, conversion to
//! volts, enqueue), the IMU tick's driver work (both chips' reads over an I2C that answers
//! at once), one screen drawn into a 128×64 buffer (the display model, the health overlay
//! and the SD mark) and the session-log records (IMU, pulse) formatted with `seq`.
//!
//! Stack: each workload runs on a freshly painted stack and `board stack_<name> <bytes>`
//! gives what it used below `main`'s frame (≤ 256 B below that frame are not painted: a
//! smaller use reads as up to 256 B); with one task per priority level on the board, the
//! preempting tasks' stacks add up (docs/board.md, "Stack under preemption").
//!
//! Output: `board <name> <worst instructions> <bytes>` lines, then `done`. Run with
//! `cargo qemu --bin qemu_board`; the numbers feed `firmware::board::schedule::BOARD_COSTS`
//! (docs/board.md, "Real-time structure").
#![no_std]
#![no_main]

#[path = "support/exit.rs"]
mod exit;
#[path = "support/icount.rs"]
mod icount;
#[path = "support/stack.rs"]
#[allow(dead_code)]
mod stack;

use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::{ErrorType as I2cErrorType, I2c, Operation as I2cOp};
use embedded_hal::spi::{ErrorType as SpiErrorType, Operation as SpiOp, SpiDevice};
use firmware::Vec3;
use firmware::app::DisplayModel;
use firmware::board::health::{self, BatteryState, Fault};
use firmware::drivers::ads131m04::Ads131m04;
use firmware::drivers::imu::{BMI160_CHIP_ID, Imu, LSM303AGR_MAG_ID};
use firmware::guidance::Status;
use firmware::session_log::Recorder;
use heapless::spsc::Queue;
use icount::InstructionCounter;

/// Repetitions of each measurement (the worst is reported).
const REPEATS: u32 = 20;

/// An SPI device answering every transfer with one valid ADS131M04 frame (24-bit words:
/// status, four channels, CRC over the first five words).
struct FrameSpi {
    frame: [u8; 18],
}

impl FrameSpi {
    fn new() -> Self {
        let mut frame = [0u8; 18];
        let words: [u32; 5] = [0x05_0000, 0x12_3456, 0xED_CBA9, 0x00_1234, 0x7F_0000];
        for (k, w) in words.iter().enumerate() {
            let b = w.to_be_bytes();
            frame[3 * k..3 * k + 3].copy_from_slice(&b[1..4]);
        }
        let crc = crc16(&frame[..15]).to_be_bytes();
        frame[15] = crc[0];
        frame[16] = crc[1];
        Self { frame }
    }
}

/// CRC-16-CCITT (0x1021, seed 0xFFFF), the ADS131M04's.
fn crc16(bytes: &[u8]) -> u16 {
    bytes.iter().fold(0xFFFF_u16, |mut crc, &b| {
        crc ^= u16::from(b) << 8;
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

impl SpiErrorType for FrameSpi {
    type Error = core::convert::Infallible;
}

impl SpiDevice for FrameSpi {
    fn transaction(&mut self, ops: &mut [SpiOp<'_, u8>]) -> Result<(), Self::Error> {
        for op in ops {
            match op {
                SpiOp::TransferInPlace(buf) | SpiOp::Read(buf) => {
                    for (b, f) in buf.iter_mut().zip(self.frame.iter().cycle()) {
                        *b = core::hint::black_box(*f);
                    }
                }
                SpiOp::Transfer(read, _) => {
                    for (b, f) in read.iter_mut().zip(self.frame.iter().cycle()) {
                        *b = core::hint::black_box(*f);
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// DRDY is asserted (as in the board's interrupt).
struct Low;

impl embedded_hal::digital::ErrorType for Low {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::InputPin for Low {
    fn is_high(&mut self) -> Result<bool, Self::Error> {
        Ok(false)
    }
    fn is_low(&mut self) -> Result<bool, Self::Error> {
        Ok(true)
    }
}

/// An I2C bus on which the BMI160 and the LSM303AGR answer their ID reads and every other
/// read with a fixed pattern.
struct ImuBus;

impl I2cErrorType for ImuBus {
    type Error = core::convert::Infallible;
}

impl I2c for ImuBus {
    fn transaction(&mut self, address: u8, ops: &mut [I2cOp<'_>]) -> Result<(), Self::Error> {
        let mut reg = 0xFFu8;
        for op in ops {
            match op {
                I2cOp::Write(w) => reg = w.first().copied().unwrap_or(0xFF),
                I2cOp::Read(r) => {
                    let id = match (address, reg) {
                        (0x68, 0x00) => Some(BMI160_CHIP_ID),
                        (0x1E, 0x4F) => Some(LSM303AGR_MAG_ID),
                        _ => None,
                    };
                    for (k, b) in r.iter_mut().enumerate() {
                        *b = core::hint::black_box(id.unwrap_or(0x35u8.wrapping_mul(k as u8 + 1)));
                    }
                }
            }
        }
        Ok(())
    }
}

/// No delay (the measurement counts instructions, not waits).
struct NoDelay;

impl DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}

/// A 128×64 one-bit frame laid out as the SSD1306's buffer (pages of 8 rows).
struct FrameBuf {
    buf: [u8; 1024],
}

impl OriginDimensions for FrameBuf {
    fn size(&self) -> Size {
        Size::new(128, 64)
    }
}

impl DrawTarget for FrameBuf {
    type Color = BinaryColor;
    type Error = core::convert::Infallible;

    fn draw_iter<I: IntoIterator<Item = Pixel<BinaryColor>>>(
        &mut self,
        pixels: I,
    ) -> Result<(), Self::Error> {
        for Pixel(p, c) in pixels {
            if let (Ok(x @ 0..128), Ok(y @ 0..64)) = (usize::try_from(p.x), usize::try_from(p.y)) {
                let i = x + (y / 8) * 128;
                let bit = 1u8 << (y % 8);
                if c.is_on() {
                    self.buf[i] |= bit;
                } else {
                    self.buf[i] &= !bit;
                }
            }
        }
        Ok(())
    }
}

/// One simultaneous sample of the three coils (as the board queues it).
#[derive(Clone, Copy)]
struct Sample {
    volts: [f32; 3],
    clipped: bool,
}

/// Runs `f` on a freshly painted stack; returns what it used below the caller's frame, B.
fn own_stack<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let stack_top = 0x2000_0000 + stack::size();
    let base = stack_top - cortex_m::register::msp::read() as usize;
    stack::paint();
    let out = f();
    (out, stack::high_water().saturating_sub(base))
}

#[entry]
fn main() -> ! {
    let mut counter = InstructionCounter::start_on_painted_stack();
    let mut ok = true;

    // The DRDY interrupt's work: read, check, convert, enqueue (SPI wait excluded).
    let mut adc = Ads131m04::new(FrameSpi::new(), Low);
    let mut queue: Queue<Sample, 64> = Queue::new();
    let mut worst = 0;
    let ((), drdy_stack) = own_stack(|| {
        for _ in 0..REPEATS {
            let (r, n) = counter.measure(|| {
                let sample = match adc.read_frame() {
                    Ok(frame) => {
                        let v = adc.to_volts(&frame);
                        Sample {
                            volts: [v[0], v[1], v[2]],
                            clipped: frame.coils_saturated(),
                        }
                    }
                    Err(_) => Sample {
                        volts: [0.0; 3],
                        clipped: true,
                    },
                };
                queue.enqueue(sample).is_ok()
            });
            ok &= r;
            worst = n.max(worst);
            ok &= queue
                .dequeue()
                .is_some_and(|s| !s.clipped && s.volts[0] != 0.0);
        }
    });
    hprintln!("board drdy_isr {} 18", worst);
    hprintln!("board stack_drdy_isr {}", drdy_stack);

    // The IMU tick's driver work (I2C waits excluded).
    match Imu::with_mounting(
        ImuBus,
        ImuBus,
        firmware::board::REFERENCE.imu.mounting,
        &mut NoDelay,
    ) {
        Ok(mut imu) => {
            let mut worst = 0;
            let ((), imu_stack) = own_stack(|| {
                for _ in 0..REPEATS {
                    let (r, n) = counter.measure(|| core::hint::black_box(imu.read()));
                    ok &= r.is_ok();
                    worst = n.max(worst);
                }
            });
            hprintln!("board imu_read {} 18", worst);
            hprintln!("board stack_imu_read {}", imu_stack);
        }
        Err(_) => {
            hprintln!("board imu_read failed");
            ok = false;
        }
    }

    // One screen: a localized victim with every line filled, a fault box, the battery
    // gauge and the SD mark (the most the board draws).
    let model = DisplayModel {
        status: Status::Localized,
        arrow_deg: Some(37.0),
        distance_m: Some(12.34),
        horizontal_m: Some(12.0),
        depth_m: Some(1.24),
        walk_m: Some(12.0),
        uncertainty_m: Some(0.4),
        victims: 3,
        overlap: true,
        pulses: 12345,
        t_s: 1234.5,
        lift: false,
        ..DisplayModel::default()
    };
    let battery = BatteryState {
        volts: 3.71,
        percent: 23.0,
        low: false,
    };
    let mut frame = FrameBuf { buf: [0; 1024] };
    let mut worst = 0;
    let ((), render_stack) = own_stack(|| {
        for _ in 0..REPEATS {
            let (r, n) = counter.measure(|| {
                frame.clear(BinaryColor::Off).is_ok()
                    && firmware::display::draw(&model, &mut frame).is_ok()
                    && health::draw_overlay(Some(Fault::Imu), Some(battery), &mut frame).is_ok()
                    && health::draw_sd_mark(Some("SD ERR"), &mut frame).is_ok()
            });
            ok &= r;
            worst = n.max(worst);
        }
    });
    let lit: u32 = frame.buf.iter().map(|b| b.count_ones()).sum();
    ok &= lit > 100;
    hprintln!("board render {} 1024", worst);
    hprintln!("board stack_render {}", render_stack);

    // Session-log records with seq (times past a day, six-digit values).
    let mut rec = Recorder::new(heapless::String::<512>::new());
    let (acc, gyr, mag) = (
        Vec3::new(-0.123_456, 9.812_345, 0.456_789),
        Vec3::new(0.012_345, -0.023_456, 0.003_456),
        Vec3::new(21.234_56, -3.456_78, 42.345_67),
    );
    let (mut worst, mut bytes) = (0, 0);
    let ((), log_stack) = own_stack(|| {
        for k in 0..REPEATS {
            rec.writer().clear();
            let t = 86_400.0 + f64::from(k) * 0.01 + 0.000_123;
            let (r, n) = counter.measure(|| rec.imu(t, &acc, &gyr, Some(&mag)));
            ok &= r.is_ok();
            worst = n.max(worst);
            bytes = bytes.max(rec.writer_ref().len());
        }
    });
    hprintln!("board log_imu {} {}", worst, bytes);
    hprintln!("board stack_log_imu {}", log_stack);
    let h = Vec3::new(1.234_567e-7, -2.345_678e-7, 3.456_789e-8);
    let (mut worst, mut bytes) = (0, 0);
    for k in 0..REPEATS {
        rec.writer().clear();
        let t = 86_400.0 + f64::from(k) * 0.7 + 0.000_123;
        let (r, n) = counter.measure(|| rec.pulse(t, &h, Some(3)));
        ok &= r.is_ok();
        worst = n.max(worst);
        bytes = bytes.max(rec.writer_ref().len());
    }
    hprintln!("board log_pulse {} {}", worst, bytes);
    hprintln!("board stack_high_water {}", stack::high_water());
    hprintln!("done");
    exit::exit(ok)
}
