//! The firmware's pipeline behind `replay`: the application state machine
//! [`firmware::app::Receiver`] (IMU samples → attitude and pedestrian dead reckoning →
//! displacement and attitude per pulse → SOGs filter → search control → display model),
//! fed from a log. Exactly the firmware's code; the replay line carries the display's
//! arrow and status word.
use crate::receiver_config::ReceiverConfig;
use crate::replay::{Estimator, ReplayLine, VictimEstimate};
use crate::session::{Header, Imu, Pulse};
use crate::world::earth_field_ut;
use firmware::Vec3;
use firmware::app::{AppConfig, Receiver};
use firmware::estimate::SogConfig;
use firmware::motion::MotionConfig;

/// Earth field assumed when the header gives none: 48 µT at 63° inclination.
const DEFAULT_EARTH: (f64, f64) = (48.0, 63.0);

/// The firmware's application as a replay [`Estimator`].
pub struct SogReplay {
    /// Boxed: the receiver holds the ≈ 63 KB filter.
    receiver: Box<Receiver>,
    /// Log time of the first record: the firmware runs on times relative to it (f32).
    t0: Option<f64>,
}

/// The filter configuration a receiver with `receiver` settings uses, on top of `base`
/// (which keeps, e.g., the scale prior that `AppConfig::new` took from the step model).
pub fn sog_config(receiver: &ReceiverConfig, base: SogConfig) -> SogConfig {
    SogConfig {
        m_min: receiver.m_min as f32,
        m_max: receiver.m_max as f32,
        depth_min: receiver.victim_depth_range_m[0] as f32,
        depth_max: receiver.victim_depth_range_m[1] as f32,
        receiver_height: receiver.receiver_height_m as f32,
        sigma_bkg: receiver.pulse_noise.sigma_bkg_a_per_m as f32,
        k_sen: receiver.pulse_noise.k_sen as f32,
        ..base
    }
}

/// The application configuration for a log with `header` and `receiver` settings.
pub fn app_config(header: &Header, receiver: &ReceiverConfig) -> AppConfig {
    let earth = header
        .earth_field_ut
        .unwrap_or_else(|| earth_field_ut(DEFAULT_EARTH.0, DEFAULT_EARTH.1));
    let step = receiver.pdr.as_ref().map(|p| p.step_length_m as f32);
    let earth = Vec3::new(earth[0] as f32, earth[1] as f32, earth[2] as f32);
    let mut motion = MotionConfig::new(earth, step);
    motion.imu_hz = header.imu_hz as f32;
    let mut cfg = AppConfig::new(earth, step);
    cfg.motion = motion;
    cfg.sog = sog_config(receiver, cfg.sog);
    cfg.guidance.receiver_height_m = cfg.sog.receiver_height;
    cfg
}

impl SogReplay {
    /// A pipeline for a log with `header`, configured from `receiver`; an error when the
    /// receiver configuration is inconsistent (e.g. `m_min > m_max`).
    pub fn new(header: &Header, receiver: &ReceiverConfig) -> anyhow::Result<Self> {
        let receiver = Receiver::new(app_config(header, receiver)).map_err(|e| {
            anyhow::anyhow!("receiver configuration refused by the firmware: {e:?}")
        })?;
        Ok(Self {
            receiver: Box::new(receiver),
            t0: None,
        })
    }

    fn rel(&mut self, t: f64) -> f32 {
        let t0 = *self.t0.get_or_insert(t);
        (t - t0) as f32
    }

    /// Pulses refused by the firmware so far.
    pub fn refused(&self) -> usize {
        self.receiver.stats().pulses_refused as usize
    }

    /// The application (read-only).
    pub fn receiver(&self) -> &Receiver {
        &self.receiver
    }
}

fn v3(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

impl Estimator for SogReplay {
    fn on_imu(&mut self, imu: &Imu) {
        let t = self.rel(imu.t);
        let mag = imu.mag.as_ref().map(v3);
        // A refused sample is counted by the receiver and otherwise skipped.
        let _ = self
            .receiver
            .on_imu(t, &v3(&imu.acc), &v3(&imu.gyr), mag.as_ref());
    }

    fn on_pulse(&mut self, pulse: &Pulse) -> ReplayLine {
        let t = self.rel(pulse.t);
        let src = pulse.src.map(|s| u8::try_from(s).unwrap_or(u8::MAX));
        // A refused pulse leaves the receiver unchanged: report its current state.
        let display = self
            .receiver
            .on_pulse(t, &v3(&pulse.h), src)
            .unwrap_or_else(|_| self.receiver.display_model());
        let yaw = f64::from(self.receiver.motion().attitude().0.z);
        // Every listed victim with an estimate (several transmitters: one mixture each),
        // the one the guidance leads to first; positions relative to the receiver now.
        let bank = self.receiver.victims();
        let target = self.receiver.target();
        let victims = target
            .into_iter()
            .chain(bank.active().map(|(i, _)| i).filter(|i| Some(*i) != target))
            .filter_map(|i| {
                let v = bank.get(i)?;
                let e = v.estimate()?;
                let p = v.position_now()?;
                let p = [p.x, p.y, p.z].map(f64::from);
                let cov: [f64; 9] = core::array::from_fn(|i| f64::from(e.cov[(i / 3, i % 3)]));
                Some(VictimEstimate::new(p, cov, yaw))
            })
            .collect();
        ReplayLine {
            t: pulse.t,
            n_components: self.receiver.filter().len() as u32,
            arrow_deg: display.arrow_deg.map(f64::from),
            status: Some(display.status.as_str().to_string()),
            victims,
        }
    }
}
