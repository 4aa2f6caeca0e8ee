//! The firmware's pipeline behind `replay`: IMU samples → attitude and pedestrian dead
//! reckoning (`firmware::motion`) → displacement and attitude per pulse → the SOGs
//! filter (`firmware::estimate`). Exactly the firmware's code, fed from a log.
use crate::receiver_config::ReceiverConfig;
use crate::replay::{Estimator, ReplayLine, VictimEstimate};
use crate::session::{Header, Imu, Pulse};
use crate::world::earth_field_ut;
use firmware::Vec3;
use firmware::estimate::{self, Attitude, DefaultSog, Estimator as _, SogConfig};
use firmware::motion::{Motion, MotionConfig, MotionError};

/// Earth field assumed when the header gives none: 48 µT at 63° inclination.
const DEFAULT_EARTH: (f64, f64) = (48.0, 63.0);

/// The firmware's motion + SOGs pipeline as a replay [`Estimator`].
pub struct SogReplay {
    motion: Motion,
    filter: Box<DefaultSog>,
    /// Log time of the first record: the firmware runs on times relative to it (f32).
    t0: Option<f64>,
    /// Pulses the filter refused (bad input), reported on stderr at the end.
    refused: usize,
}

/// The filter configuration a receiver with `receiver` settings uses.
pub fn sog_config(receiver: &ReceiverConfig) -> SogConfig {
    SogConfig {
        m_min: receiver.m_min as f32,
        m_max: receiver.m_max as f32,
        depth_min: receiver.victim_depth_range_m[0] as f32,
        depth_max: receiver.victim_depth_range_m[1] as f32,
        receiver_height: receiver.receiver_height_m as f32,
        sigma_bkg: receiver.pulse_noise.sigma_bkg_a_per_m as f32,
        k_sen: receiver.pulse_noise.k_sen as f32,
        ..SogConfig::default().with_calibrated_step(receiver.pdr.is_some())
    }
}

impl SogReplay {
    /// A pipeline for a log with `header`, configured from `receiver`; an error when the
    /// receiver configuration is inconsistent (e.g. `m_min > m_max`).
    pub fn new(header: &Header, receiver: &ReceiverConfig) -> anyhow::Result<Self> {
        let earth = header
            .earth_field_ut
            .unwrap_or_else(|| earth_field_ut(DEFAULT_EARTH.0, DEFAULT_EARTH.1));
        let step = receiver.pdr.as_ref().map(|p| p.step_length_m as f32);
        let earth = Vec3::new(earth[0] as f32, earth[1] as f32, earth[2] as f32);
        let mut cfg = MotionConfig::new(earth, step);
        cfg.imu_hz = header.imu_hz as f32;
        let filter = DefaultSog::new(sog_config(receiver)).map_err(|e| {
            anyhow::anyhow!("receiver configuration refused by the estimator: {e:?}")
        })?;
        Ok(Self {
            motion: Motion::new(cfg),
            filter: Box::new(filter),
            t0: None,
            refused: 0,
        })
    }

    fn rel(&mut self, t: f64) -> f32 {
        let t0 = *self.t0.get_or_insert(t);
        (t - t0) as f32
    }

    /// Pulses refused by the filter so far.
    pub fn refused(&self) -> usize {
        self.refused
    }
}

fn v3(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

impl Estimator for SogReplay {
    fn on_imu(&mut self, imu: &Imu) {
        let t = self.rel(imu.t);
        let mag = imu.mag.as_ref().map(v3);
        let result = self
            .motion
            .on_imu_sample(t, &v3(&imu.acc), &v3(&imu.gyr), mag.as_ref());
        if let Err(MotionError::Gap { .. }) = result {
            // A gap in the IMU stream: restart integration from here (the displacement
            // over the gap is inflated by the motion module).
            let _ = self.motion.resync(t);
            let _ = self
                .motion
                .on_imu_sample(t, &v3(&imu.acc), &v3(&imu.gyr), mag.as_ref());
        }
    }

    fn on_pulse(&mut self, pulse: &Pulse) -> ReplayLine {
        let t = self.rel(pulse.t);
        let d = self.motion.take_displacement(t);
        let motion = estimate::Displacement {
            translation: d.translation,
            rotation: d.rotation,
            cov: d.cov,
        };
        let (rpy, cov) = self.motion.attitude();
        let attitude = Attitude { rpy, cov };
        let p = estimate::Pulse { h: v3(&pulse.h), t };
        if self.filter.step(&motion, &attitude, &p).is_err() {
            self.refused += 1;
        }
        let victims = self
            .filter
            .estimate()
            .map(|e| {
                let p = [e.p.x, e.p.y, e.p.z].map(f64::from);
                let cov: [f64; 9] = core::array::from_fn(|i| f64::from(e.cov[(i / 3, i % 3)]));
                VictimEstimate::new(p, cov, f64::from(rpy.z))
            })
            .into_iter()
            .collect();
        ReplayLine {
            t: pulse.t,
            n_components: self.filter.len() as u32,
            arrow_deg: None,
            status: None,
            victims,
        }
    }
}
