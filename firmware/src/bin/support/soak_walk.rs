//! On-target generator of a long search for the soak run (`qemu_soak`): a rescuer walking
//! circles around a buried transmitter, stopping and turning in place, with the IMU
//! samples (100 Hz) and beacon pulses (1 Hz) the receiver would see, drawn from a seeded
//! PRNG. An hour of inputs is far too large to embed, so they are made on the fly.
//!
//! The world (frame W: x north, y west, z up; the session-log conventions):
//! - the receiver is held level at z = 0, its x axis along the walking direction;
//! - the transmitter is buried at `VICTIM` (1.5 m under the snow, the receiver 1 m above
//!   it), with a horizontal moment of 0.01 A·m²;
//! - one cycle of `CYCLE_S` seconds: walk a circle of radius `RADIUS_M` around a centre
//!   `CENTRE_OFFSET_M` north of the victim (2–22 m from it) at 1.8 steps/s of 0.56 m,
//!   then stand still, then turn in place (build with `SOAK_WALK_ONLY=1` to walk only).
//!
//! Sensors: specific force with the walking bob (2 cm at the step rate, ≈ 2.6 m/s²) and
//! the centripetal acceleration, rate and earth field rotated into the body frame, white
//! noise on each; pulses are the dipole field (ICRA 2006 eq. 5) in the body frame with the
//! receiver's noise model (σ² = σ_bkg² + (k_sen·|h|)², as the filter assumes), reported
//! with the largest component positive as the front end does (sign-ambiguous).
use core::f32::consts::TAU;
use firmware::frame::rotation_from_rpy;
use firmware::timebase::Instant;
use firmware::{Vec3, dipole};

/// Standard gravity, m/s².
const G: f32 = 9.80665;
/// IMU sample period, s (100 Hz).
pub const IMU_DT: f32 = 0.01;
/// IMU samples per pulse period (1 Hz pulses).
pub const IMU_PER_PULSE: u32 = 100;
/// Step length (m) and cadence (Hz): the receiver is calibrated to this step length.
pub const STEP_LENGTH_M: f32 = 0.56;
const CADENCE_HZ: f32 = 1.8;
/// Vertical bob amplitude, m.
const BOB_M: f32 = 0.02;
/// Circle radius and the circle centre's offset north of the victim, m.
const RADIUS_M: f32 = 10.0;
const CENTRE_OFFSET_M: f32 = 12.0;
/// One cycle: walking, then standing, then turning in place, s.
const CYCLE_S: f32 = 300.0;
const WALK_S: f32 = if option_env!("SOAK_WALK_ONLY").is_some() {
    CYCLE_S
} else {
    240.0
};
const STAND_S: f32 = 30.0;
/// Turning rate in place, rad/s.
const TURN_RATE: f32 = 0.4;
/// Transmitter position in W, m, and moment, A·m².
pub const VICTIM: [f32; 3] = [0.0, 0.0, -2.5];
const MOMENT: [f32; 3] = [0.0095, 0.003, 0.0];
/// Earth field in W, µT (48 µT, 63° inclination).
pub const EARTH_UT: [f32; 3] = [21.8, 0.0, -42.8];
/// IMU noise: accelerometer m/s², gyroscope rad/s, magnetometer µT (per axis, σ).
const SIGMA_ACC: f32 = 0.05;
const SIGMA_GYR: f32 = 0.003;
const SIGMA_MAG: f32 = 0.3;
/// Pulse noise (the filter's defaults): background A/m and proportional part.
const SIGMA_BKG: f32 = 2.59e-9;
const K_SEN: f32 = 0.03;

/// A xorshift64* generator (small, deterministic, no_std).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a non-zero seed.
    pub fn new(seed: u64) -> Self {
        Self(seed | 1)
    }

    fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in (0, 1].
    fn uniform(&mut self) -> f32 {
        ((self.next_u64() >> 40) as f32 + 1.0) / (1u64 << 24) as f32
    }

    /// Standard normal (Box–Muller).
    pub fn gauss(&mut self) -> f32 {
        let (u1, u2) = (self.uniform(), self.uniform());
        libm::sqrtf(-2.0 * libm::logf(u1)) * libm::cosf(TAU * u2)
    }

    fn gauss3(&mut self, sigma: f32) -> Vec3 {
        Vec3::new(self.gauss(), self.gauss(), self.gauss()) * sigma
    }
}

/// One IMU sample in the body frame.
pub struct ImuSample {
    /// Specific force, m/s².
    pub acc: Vec3,
    /// Rate, rad/s.
    pub gyr: Vec3,
    /// Flux density, µT.
    pub mag: Vec3,
}

/// The walking world and its sensors.
pub struct Walk {
    rng: Rng,
    /// IMU samples so far (the time base: `t = k · IMU_DT`, no accumulated rounding).
    k: u32,
    /// Receiver position in W, m (f32 is ample: it stays within 25 m of the origin).
    p: Vec3,
    /// Heading, rad (kept in (−π, π]).
    yaw: f32,
    /// Distance walked, m.
    walked: f32,
}

/// What the receiver does at time `t` in the cycle: (speed m/s, yaw rate rad/s, bobbing).
fn activity(t: f32) -> (f32, f32, bool) {
    let c = t % CYCLE_S;
    let v = STEP_LENGTH_M * CADENCE_HZ;
    if c < WALK_S {
        (v, v / RADIUS_M, true)
    } else if c < WALK_S + STAND_S {
        (0.0, 0.0, false)
    } else {
        (0.0, TURN_RATE, false)
    }
}

impl Walk {
    /// The rescuer on the circle's southernmost point, heading east… along the circle.
    pub fn new(seed: u64) -> Self {
        Self {
            rng: Rng::new(seed),
            k: 0,
            p: Vec3::new(CENTRE_OFFSET_M - RADIUS_M, 0.0, 0.0),
            // Counter-clockwise (seen from above) around the centre to the north.
            yaw: -core::f32::consts::FRAC_PI_2,
            walked: 0.0,
        }
    }

    /// Time of the last sample, s.
    pub fn t(&self) -> f32 {
        self.k as f32 * IMU_DT
    }

    /// Time stamp of the last sample (the board's integer clock).
    pub fn now(&self) -> Instant {
        Instant::from_micros(u64::from(self.k) * 10_000)
    }

    /// Advances by one IMU period and returns the sample.
    pub fn next_imu(&mut self) -> ImuSample {
        self.k = self.k.wrapping_add(1);
        let t = self.t();
        let (v, yaw_rate, bob) = activity(t);
        self.yaw = wrap_pi(self.yaw + yaw_rate * IMU_DT);
        let (s, c) = (libm::sinf(self.yaw), libm::cosf(self.yaw));
        self.p += Vec3::new(c, s, 0.0) * (v * IMU_DT);
        self.walked += v * IMU_DT;
        // Centripetal (to the left of the heading) and the bob's vertical acceleration.
        let w = TAU * CADENCE_HZ;
        let a_z = if bob {
            -BOB_M * w * w * libm::cosf(w * t)
        } else {
            0.0
        };
        let a = Vec3::new(-s, c, 0.0) * (v * yaw_rate) + Vec3::new(0.0, 0.0, a_z + G);
        let r_t = rotation_from_rpy(&Vec3::new(0.0, 0.0, self.yaw)).transpose();
        let earth = Vec3::from(EARTH_UT);
        ImuSample {
            acc: r_t * a + self.rng.gauss3(SIGMA_ACC),
            gyr: Vec3::new(0.0, 0.0, yaw_rate) + self.rng.gauss3(SIGMA_GYR),
            mag: r_t * earth + self.rng.gauss3(SIGMA_MAG),
        }
    }

    /// The pulse at the current time: the noisy field in the body frame (largest
    /// component positive), or `None` if the model cannot be evaluated.
    pub fn pulse(&mut self) -> Option<Vec3> {
        let r = self.p - Vec3::from(VICTIM);
        let h_w = dipole::field(&r, &Vec3::from(MOMENT)).ok()?;
        let h = rotation_from_rpy(&Vec3::new(0.0, 0.0, self.yaw)).transpose() * h_w;
        let sigma = libm::sqrtf(SIGMA_BKG * SIGMA_BKG + (K_SEN * h.norm()) * (K_SEN * h.norm()));
        let h = h + self.rng.gauss3(sigma);
        let largest = h
            .iter()
            .fold(0.0f32, |a, &x| if x.abs() > a.abs() { x } else { a });
        Some(if largest < 0.0 { -h } else { h })
    }

    /// Distance walked so far, m.
    pub fn walked_m(&self) -> f32 {
        self.walked
    }

    /// The true victim offset from the receiver in `G_k` (W axes), m.
    pub fn truth(&self) -> Vec3 {
        Vec3::from(VICTIM) - self.p
    }
}

fn wrap_pi(a: f32) -> f32 {
    let mut a = a % TAU;
    if a > core::f32::consts::PI {
        a -= TAU;
    } else if a <= -core::f32::consts::PI {
        a += TAU;
    }
    a
}
