//! Runs a session log through the firmware's application ([`Receiver`]) and records,
//! per pulse, what it answered and showed, with the truth beside it when known.
use crate::io::receiver_config::ReceiverConfig;
use crate::io::session::{Record, Session};
use crate::io::sog_replay::app_config;
use crate::stamp;
use crate::world::physics::V3;
use firmware::Vec3;
use firmware::app::{AppError, AppStats, DisplayModel, Receiver};
use firmware::estimate::VictimEstimate;

/// What the application did with one pulse.
#[derive(Debug, Clone)]
pub struct PulseStep {
    /// Log time of the pulse, s.
    pub t: f64,
    /// The display after the pulse, or why the pulse was refused.
    pub result: Result<DisplayModel, AppError>,
    /// The estimator's belief after the pulse.
    pub estimate: Option<VictimEstimate>,
    /// The true victim offset from the receiver in `G_k` (W axes), m, when known.
    pub truth: Option<V3>,
    /// Components in the mixture after the pulse.
    pub components: usize,
}

impl PulseStep {
    /// 3-D error of the estimate against the truth, m (`None` without either).
    pub fn error_m(&self) -> Option<f64> {
        let (e, t) = (self.estimate.as_ref()?, self.truth.as_ref()?);
        Some((V3::new(e.p.x.into(), e.p.y.into(), e.p.z.into()) - t).norm())
    }

    /// Whether anything the application reported is NaN or infinite.
    pub fn non_finite(&self) -> bool {
        let display_bad = self.result.as_ref().is_ok_and(|d| {
            [
                d.arrow_deg,
                d.distance_m,
                d.horizontal_m,
                d.depth_m,
                d.walk_m,
            ]
            .iter()
            .flatten()
            .chain(d.uncertainty_m.iter())
            .any(|x| !x.is_finite())
        });
        let estimate_bad = self
            .estimate
            .as_ref()
            .is_some_and(|e| !e.p.iter().chain(e.cov.iter()).all(|x| x.is_finite()));
        display_bad || estimate_bad
    }
}

/// A display read between pulses (the board redraws it on each pulse, and at least once a
/// second without them).
#[derive(Debug, Clone, Copy)]
pub struct DisplayRead {
    /// Log time, s.
    pub t: f64,
    /// What the screen showed.
    pub display: DisplayModel,
}

/// Everything one run recorded.
#[derive(Debug, Clone)]
pub struct Trace {
    /// One entry per pulse record.
    pub pulses: Vec<PulseStep>,
    /// The display once per `display_every_s` of IMU time.
    pub displays: Vec<DisplayRead>,
    /// IMU samples refused, with their errors.
    pub imu_errors: Vec<(f64, AppError)>,
    /// The application's counters at the end.
    pub stats: AppStats,
    /// Magnetometer samples the attitude filter rejected as disturbed.
    pub mag_rejected: u32,
}

impl Trace {
    /// The pulses with `t` in `[t0, t1)`.
    pub fn pulses_in(&self, t0: f64, t1: f64) -> impl Iterator<Item = &PulseStep> {
        self.pulses.iter().filter(move |p| p.t >= t0 && p.t < t1)
    }

    /// The last pulse with an estimate and a truth.
    pub fn final_error_m(&self) -> Option<f64> {
        self.pulses.iter().rev().find_map(PulseStep::error_m)
    }

    /// Whether any pulse produced a NaN or infinite output.
    pub fn any_non_finite(&self) -> bool {
        self.pulses.iter().any(PulseStep::non_finite)
    }
}

fn v3(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

/// The victim offset at the truth record nearest to `t` (truth records are written at
/// every pulse time).
fn truth_at(truth: &[(f64, V3)], t: f64) -> Option<V3> {
    let i = truth.partition_point(|(tt, _)| *tt < t);
    let near = [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|k| truth.get(k))
        .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))?;
    ((near.0 - t).abs() < 0.05).then_some(near.1)
}

/// Victim-minus-receiver offsets of the first victim from a truth log.
pub fn truth_offsets(truth: &Session) -> Vec<(f64, V3)> {
    truth
        .truth()
        .filter_map(|r| {
            let v = r.victims.first()?;
            Some((r.t, V3::from(v.p) - V3::from(r.p)))
        })
        .collect()
}

/// Runs `session` through a fresh [`Receiver`] configured from `receiver`; `truth`
/// (a truth log) adds the true offsets; the display is read every `display_every_s`.
pub fn drive(
    session: &Session,
    receiver: &ReceiverConfig,
    truth: Option<&Session>,
    display_every_s: f64,
) -> anyhow::Result<Trace> {
    drive_with(
        session,
        app_config(&session.header, receiver),
        truth,
        display_every_s,
    )
}

/// [`drive`] with the application's configuration given (e.g. another dead-reckoning
/// noise, for an ablation).
pub fn drive_with(
    session: &Session,
    cfg: firmware::app::AppConfig,
    truth: Option<&Session>,
    display_every_s: f64,
) -> anyhow::Result<Trace> {
    let mut rx =
        Box::new(Receiver::new(cfg).map_err(|e| anyhow::anyhow!("configuration refused: {e:?}"))?);
    let truth = truth.map(truth_offsets).unwrap_or_default();
    let t0 = session.records.first().map_or(0.0, Record::t);
    let mut trace = Trace {
        pulses: Vec::new(),
        displays: Vec::new(),
        imu_errors: Vec::new(),
        stats: AppStats::default(),
        mag_rejected: 0,
    };
    let mut next_display = t0;
    for r in &session.records {
        match r {
            Record::Imu(s) => {
                let t = stamp(s.t - t0);
                let mag = s.mag.as_ref().map(v3);
                if let Err(e) = rx.on_imu(t, &v3(&s.acc), &v3(&s.gyr), mag.as_ref()) {
                    trace.imu_errors.push((s.t, e));
                }
                if s.t >= next_display {
                    trace.displays.push(DisplayRead {
                        t: s.t,
                        display: rx.display_model(),
                    });
                    next_display += display_every_s;
                }
            }
            Record::Pulse(p) => {
                let src = p.src.map(|s| u8::try_from(s).unwrap_or(u8::MAX));
                let result = rx.on_pulse(stamp(p.t - t0), &v3(&p.h), src);
                trace.pulses.push(PulseStep {
                    t: p.t,
                    result,
                    estimate: rx.estimate(),
                    truth: truth_at(&truth, p.t),
                    components: rx.filter().len(),
                });
            }
            _ => {}
        }
    }
    trace.stats = *rx.stats();
    trace.mag_rejected = rx
        .motion()
        .attitude_filter()
        .map_or(0, |a| a.stats().mag_rejected);
    Ok(trace)
}
