//! One rescuer's log on its own: the firmware's dead reckoning (`firmware::motion`) as a
//! track with a growing covariance, and the firmware's SOGs estimator (through
//! `firmware::app::Receiver`) run once per `src` track, giving each track's best victim
//! estimate relative to the receiver and its signature.
use super::signature::{self, Signature};
use crate::io::receiver_config::ReceiverConfig;
use crate::io::session::{Pulse, Record, Session};
use crate::io::sog_replay::app_config;
use crate::stamp;
use firmware::Vec3;
use firmware::app::Receiver;
use firmware::frame::rotation_from_rpy;
use firmware::motion::{Motion, MotionError};
use firmware::timebase::Instant;
use serde::{Deserialize, Serialize};

/// The dead-reckoned position at one pulse, in the log's own frame (start at the origin,
/// W's axes: the yaw is magnetometer-aided and absolute).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DrSample {
    /// Log time, s.
    pub t: f64,
    /// Position (north, west) relative to the start, m.
    pub p: [f64; 2],
    /// Covariance of `p` accumulated from the per-interval `Q_k` `[xx, xy, yy]`, m².
    pub cov: [f64; 3],
}

/// A track's best victim estimate: relative to the receiver at `t` (IROS 2006 eq. 18).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Log time of the pulse after which the estimate was taken, s.
    pub t: f64,
    /// Index of that pulse in [`LocalRun::dr`].
    pub dr_index: usize,
    /// Victim position relative to the receiver (north, west, up), m.
    pub p: [f64; 3],
    /// Its covariance, row-major, m².
    pub cov: [f64; 9],
    /// Estimated moment magnitude, A·m² (a field-strength signature).
    pub moment: f64,
}

impl Observation {
    /// Largest horizontal standard deviation, m.
    pub fn sigma_h(&self) -> f64 {
        let (a, b, d) = (self.cov[0], self.cov[1], self.cov[4]);
        let half = 0.5 * (a - d);
        (0.5 * (a + d) + (half * half + b * b).sqrt())
            .max(0.0)
            .sqrt()
    }
}

/// One `src` track of a log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Track {
    /// The log's `src` label (0 when absent).
    pub src: u32,
    /// Pulses in the track.
    pub pulses: usize,
    /// Signature from the pulse times.
    pub signature: Option<Signature>,
    /// The estimate with the smallest horizontal uncertainty (after [`MIN_PULSES`]).
    pub best: Option<Observation>,
}

/// A log processed on its own.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LocalRun {
    /// Dead-reckoned track: the first IMU sample (the start), then one sample per pulse
    /// (of any track) and at least one per [`DR_STEP_S`].
    pub dr: Vec<DrSample>,
    /// The `src` tracks, ordered by label.
    pub tracks: Vec<Track>,
}

/// Longest dead-reckoning interval without a pulse, s.
pub const DR_STEP_S: f64 = 1.0;

/// Pulses a track needs before its estimate may serve as an observation.
pub const MIN_PULSES: usize = 10;

fn v3(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

/// Dead reckoning in the common frame: positions and their accumulated covariance.
struct Dr {
    motion: Motion,
    rot: firmware::Mat3,
    yaw_var: f64,
    p: [f64; 2],
    cov: [f64; 3],
}

impl Dr {
    /// Takes the current attitude as that of the interval's start (before any pulse).
    fn set_start(&mut self) {
        let (rpy, c) = self.motion.attitude();
        self.rot = rotation_from_rpy(&rpy);
        self.yaw_var = f64::from(c[(2, 2)]).clamp(0.0, 1.0);
    }

    /// Closes the interval at pulse time `t` and adds its horizontal translation in W:
    /// `Δp = R_{k-1} t_k` (IROS 2006 eq. 4 composed), with covariance
    /// `R Q_t Rᵀ` + the absolute yaw variance across the step + the walk-long scale σ
    /// (treated as independent per interval: an approximation, see the report).
    fn step(&mut self, t: f32) {
        let d = self.motion.take_displacement(t);
        let tw = self.rot * d.translation;
        let qt = self.rot * d.cov.fixed_view::<3, 3>(0, 0) * self.rot.transpose();
        let (dx, dy) = (f64::from(tw.x), f64::from(tw.y));
        let s = f64::from(self.motion.scale_sigma());
        let (s2, y2) = (s * s, self.yaw_var);
        self.p = [self.p[0] + dx, self.p[1] + dy];
        self.cov[0] += f64::from(qt[(0, 0)]) + s2 * dx * dx + y2 * dy * dy;
        self.cov[1] += f64::from(qt[(0, 1)]) + s2 * dx * dy - y2 * dx * dy;
        self.cov[2] += f64::from(qt[(1, 1)]) + s2 * dy * dy + y2 * dx * dx;
        let (rpy, c) = self.motion.attitude();
        self.rot = rotation_from_rpy(&rpy);
        self.yaw_var = f64::from(c[(2, 2)]).clamp(0.0, 1.0);
    }
}

/// One `src` track's own firmware receiver (which sees only this track's pulses, and
/// every IMU sample) and what it found.
struct TrackRun {
    rx: Box<Receiver>,
    track: Track,
    times: Vec<f64>,
}

impl TrackRun {
    /// Feeds pulse `p` (at `t` s on the receiver's relative clock) and keeps the estimate
    /// with the smallest horizontal σ once the track has [`MIN_PULSES`].
    fn pulse(&mut self, t: Instant, p: &Pulse, dr_index: usize) {
        self.times.push(p.t);
        // A refused pulse leaves the receiver unchanged (counted by the firmware).
        if self.rx.on_pulse(t, &v3(&p.h), None).is_err() {
            return;
        }
        self.track.pulses += 1;
        let Some(est) = self.rx.estimate() else {
            return;
        };
        let obs = Observation {
            t: p.t,
            dr_index,
            p: [est.p.x, est.p.y, est.p.z].map(f64::from),
            cov: core::array::from_fn(|j| f64::from(est.cov[(j / 3, j % 3)])),
            moment: f64::from(est.moment.norm()),
        };
        let better = self
            .track
            .best
            .as_ref()
            .is_none_or(|b| obs.sigma_h() <= b.sigma_h());
        let finite = obs.p.iter().chain(&obs.cov).all(|v| v.is_finite());
        if self.track.pulses >= MIN_PULSES && finite && better {
            self.track.best = Some(obs);
        }
    }
}

impl Dr {
    /// One IMU sample; a gap is bridged as the firmware's application does (resynchronize
    /// and retry), other refused samples are skipped.
    fn imu(&mut self, t: f32, acc: &Vec3, gyr: &Vec3, mag: Option<&Vec3>) {
        if let Err(MotionError::Gap { .. }) = self.motion.on_imu_sample(t, acc, gyr, mag)
            && self.motion.resync(t).is_ok()
        {
            let _ = self.motion.on_imu_sample(t, acc, gyr, mag);
        }
    }
}

/// Runs the firmware's dead reckoning and one estimator per `src` track over `session`;
/// `progress(done, total)` is called now and then.
pub fn process(
    session: &Session,
    receiver: &ReceiverConfig,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<LocalRun> {
    let cfg = app_config(&session.header, receiver);
    let mut labels: Vec<u32> = session.pulses().map(|p| p.src.unwrap_or(0)).collect();
    labels.sort_unstable();
    labels.dedup();
    let mut tracks = Vec::with_capacity(labels.len());
    for &src in &labels {
        let rx = Receiver::new(cfg).map_err(|e| anyhow::anyhow!("receiver refused: {e:?}"))?;
        tracks.push(TrackRun {
            rx: Box::new(rx),
            track: Track {
                src,
                pulses: 0,
                signature: None,
                best: None,
            },
            times: Vec::new(),
        });
    }
    let mut dr = Dr {
        motion: Motion::new(cfg.motion),
        rot: firmware::Mat3::identity(),
        yaw_var: 0.0,
        p: [0.0; 2],
        cov: [0.0; 3],
    };
    let mut samples = Vec::new();
    let mut started = false;
    let t0 = session.records.first().map_or(0.0, Record::t);
    let total = session.records.len();
    for (i, r) in session.records.iter().enumerate() {
        match r {
            Record::Imu(s) => {
                let t = (s.t - t0) as f32;
                let mag = s.mag.as_ref().map(v3);
                let (acc, gyr) = (v3(&s.acc), v3(&s.gyr));
                dr.imu(t, &acc, &gyr, mag.as_ref());
                // The first interval starts at the first sample (its translation is in
                // that sample's body axes); the walk's start is the node the start fix
                // anchors.
                if !started {
                    started = true;
                    dr.set_start();
                    if samples.is_empty() {
                        samples.push(DrSample {
                            t: s.t,
                            p: [0.0; 2],
                            cov: [0.0; 3],
                        });
                    }
                }
                for tr in &mut tracks {
                    let _ = tr.rx.on_imu(stamp(s.t - t0), &acc, &gyr, mag.as_ref());
                }
                // Long stretches without pulses are cut every second: each interval's
                // translation is rotated by the attitude at its start, so the absolute
                // yaw error enters per short leg (not once over a 100 m approach).
                if samples.last().is_some_and(|l| s.t - l.t >= DR_STEP_S) {
                    dr.step(t);
                    samples.push(DrSample {
                        t: s.t,
                        p: dr.p,
                        cov: dr.cov,
                    });
                }
            }
            Record::Pulse(p) => {
                let t = (p.t - t0) as f32;
                dr.step(t);
                samples.push(DrSample {
                    t: p.t,
                    p: dr.p,
                    cov: dr.cov,
                });
                let k = labels.binary_search(&p.src.unwrap_or(0)).unwrap_or(0);
                if let Some(tr) = tracks.get_mut(k) {
                    tr.pulse(stamp(p.t - t0), p, samples.len() - 1);
                }
            }
            Record::Truth(_) => {}
        }
        if i % 20_000 == 0 {
            progress(i, total);
        }
    }
    let tracks = tracks
        .into_iter()
        .map(|tr| Track {
            signature: signature::fit(&tr.times),
            ..tr.track
        })
        .collect();
    Ok(LocalRun {
        dr: samples,
        tracks,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::scenario::{Preset, ScenarioConfig, simulate};

    /// A single-transmitter log (no `src`, as `simulate` writes it): one track, localized,
    /// with a period signature equal to the transmitter's; the dead-reckoned end point is
    /// within 3σ (of its own accumulated covariance, + 0.3 m) of the true displacement.
    #[test]
    fn single_transmitter_log_gives_one_track_and_a_consistent_dead_reckoning() {
        let sim = simulate(&ScenarioConfig::new(Preset::Paper, 3));
        let run = process(&sim.session, &sim.receiver, |_, _| {}).unwrap();
        assert_eq!(run.tracks.len(), 1);
        let t = &run.tracks[0];
        assert_eq!(t.src, 0);
        let sig = t.signature.as_ref().unwrap();
        let period = sim.draw.transmitters[0].period_s;
        assert!(
            (sig.period_s - period).abs() < 4.0 * sig.period_sigma_s + 1e-4,
            "{sig:?} vs {period}"
        );
        let best = t.best.as_ref().unwrap();
        assert!(best.sigma_h() < 3.0);
        // Dead reckoning vs truth between the first and the last sample.
        let (first, last) = (run.dr.first().unwrap(), run.dr.last().unwrap());
        let at = |t: f64| {
            let r = sim
                .truth
                .truth()
                .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()))
                .unwrap();
            [r.p[0], r.p[1]]
        };
        let (a, b) = (at(first.t), at(last.t));
        let truth = [b[0] - a[0], b[1] - a[1]];
        let err = (last.p[0] - truth[0]).hypot(last.p[1] - truth[1]);
        let c = last.cov;
        let half = 0.5 * (c[0] - c[2]);
        let sigma = (0.5 * (c[0] + c[2]) + (half * half + c[1] * c[1]).sqrt()).sqrt();
        assert!(
            err <= 3.0 * sigma + 0.3,
            "DR error {err:.2} m, σ {sigma:.2} m"
        );
        assert!(
            truth[0].hypot(truth[1]) > 20.0,
            "the walk is long enough to mean something"
        );
    }

    #[test]
    fn an_empty_log_gives_an_empty_run() {
        let s = Session::new(crate::io::session::Header::new(
            100.0,
            [21.0, 0.0, -42.0],
            true,
        ));
        let run = process(&s, &ReceiverConfig::default(), |_, _| {}).unwrap();
        assert!(run.dr.is_empty() && run.tracks.is_empty());
    }
}
