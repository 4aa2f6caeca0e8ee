//! The processing task's hardware: its pins, timers and clocks, the sample queue and the
//! shared resources' locks, behind [`firmware::board::process::Hardware`].

use super::{Sampler, bus::with_bus};
use core::mem::MaybeUninit;
use cortex_m::peripheral::DWT;
use firmware::app::{AppConfig, AppError, Receiver};
use firmware::board::health;
use firmware::board::i2c_bus::BusStats;
use firmware::board::pins;
use firmware::board::process::{Hardware, Sample};
use firmware::board::view::View;
use firmware::board::watchdog::MonotonicMs;
use firmware::drivers::button::MarkButton;
use firmware::frontend::{IfRange, RangeChange};
use heapless::spsc::Consumer;
use rtic::Mutex;
use stm32f4xx_hal::adc::Adc;
use stm32f4xx_hal::adc::config::SampleTime;
use stm32f4xx_hal::gpio::{Analog, Input, Output, PA3, PC1, PC2, PC3, PC6};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::timer::{PwmChannel, PwmHzManager};

/// The processing task's pins, timers and clocks.
pub struct ProcPins {
    pub mcu_adc: Adc<pac::ADC1>,
    pub vbat_pin: PA3<Analog>,
    pub vdda_v: f32,
    pub fault_led: PC1<Output>,
    pub if_range: PC3<Output>,
    pub mark: MarkButton<PC6<Input>>,
    pub sound_pin: PC2<Input>,
    pub buzz_timer: PwmHzManager<pac::TIM4>,
    pub buzzer: PwmChannel<pac::TIM4, 2>,
    pub ms_clock: MonotonicMs,
}

/// The hardware of one run of the processing task: its pins, the sample queue and the
/// two shared resources' locks.
pub struct Io<'a, S, V> {
    pub pins: &'a mut ProcPins,
    pub samples: &'a mut Consumer<'static, Sample>,
    pub sampler: &'a mut S,
    pub view: &'a mut V,
}

impl<S: Mutex<T = Sampler>, V: Mutex<T = Option<View>>> Hardware for Io<'_, S, V> {
    fn rearm_adc(&mut self) {
        self.sampler.lock(|s| {
            let _frame = s.adc.read_frame();
            s.drdy.clear_interrupt_pending_bit();
        });
    }

    fn write_range(&mut self, change: &RangeChange) -> bool {
        let gain_ok = self
            .sampler
            .lock(|s| s.adc.set_coil_gains(change.to.gain).is_ok());
        let r = if gain_ok { change.to } else { change.from };
        match r.if_range {
            IfRange::High => self.pins.if_range.set_low(),
            IfRange::Low => self.pins.if_range.set_high(),
        }
        gain_ok
    }

    fn queued_samples(&self) -> usize {
        self.samples.len()
    }

    fn now_ms(&mut self) -> u64 {
        self.pins.ms_clock.now_ms(DWT::cycle_count())
    }

    fn sound_low(&mut self) -> bool {
        self.pins.sound_pin.is_low()
    }

    fn mark_pressed(&mut self) -> bool {
        self.pins.mark.poll()
    }

    fn bus(&mut self) -> (bool, BusStats) {
        with_bus(|b| (b.stuck(), b.stats())).unwrap_or_default()
    }

    fn set_fault_led(&mut self, on: bool) {
        self.pins.fault_led.set_state(on.into());
    }

    fn battery_volts(&mut self) -> f32 {
        let p = &mut self.pins;
        let raw = p.mcu_adc.convert(&p.vbat_pin, SampleTime::Cycles_480);
        health::battery_volts(raw, p.vdda_v, pins::BATTERY_DIVIDER)
    }

    fn max_duty(&self) -> u16 {
        self.pins.buzzer.get_max_duty()
    }

    fn buzz(&mut self, play: Option<(u32, u16)>) {
        match play {
            Some((hz, duty)) => {
                self.pins.buzz_timer.set_period(hz.Hz());
                self.pins.buzzer.set_duty(duty);
            }
            None => self.pins.buzzer.set_duty(0),
        }
    }

    fn show(&mut self, view: View) {
        self.view.lock(|slot| *slot = Some(view));
        rtic::pend(pac::Interrupt::USART2);
    }

    fn rebuild(&mut self, receiver: &mut Receiver, cfg: AppConfig) -> Result<(), AppError> {
        rebuild(receiver, cfg)
    }
}

/// Builds a new receiver for `cfg` in the place of `receiver` (≈ 88 KB: never on the
/// stack); the old one is left as it was when `cfg` is refused.
fn rebuild(receiver: &mut Receiver, cfg: AppConfig) -> Result<(), AppError> {
    // SAFETY: `MaybeUninit<Receiver>` has `Receiver`'s layout, the pointer comes from a
    // unique reference and is used only for this call, and `emplace` leaves a valid
    // receiver behind (it checks `cfg` before it writes). The old receiver is forgotten,
    // not dropped (as `ptr::write` does): it owns no heap and no device, only inline
    // `heapless` buffers of plain data, so nothing leaks.
    let slot = unsafe { &mut *core::ptr::from_mut(receiver).cast::<MaybeUninit<Receiver>>() };
    Receiver::emplace(slot, cfg).map(|_| ())
}
