//! Several buried transmitters: one SOGs mixture per victim, sharing a fixed capacity.
//!
//! The front end attributes every pulse to a transmitter track (`src`, see
//! [`crate::frontend::TransmitterTracker`]). Each track that is heard gets a slot of the
//! [`VictimBank`]: its own robocentric SOGs filter ([`VictimSog`]), the receiver's
//! displacement accumulated since that victim's last pulse ([`Pending`]) and its list
//! state (number, marked). A pulse updates only its own victim's mixture, so the cost of
//! a pulse is that of one filter step, whatever the number of victims.
//!
//! # Why the displacement is composed per victim
//! The filter of IROS 2006 is robocentric: each step takes the receiver's motion since
//! *that filter's* previous pulse (eq. 4) and composes it into `G_k` (eq. 5–6). With
//! several transmitters, the pulses of victim A arrive between those of victim B, so the
//! motion pipeline's interval (closed at every pulse) is composed onto every other
//! victim's pending displacement with [`compose`] — the same `⊕` of eq. 5–6 applied to
//! two motions, with first-order covariance propagation.
//!
//! # Memory budget (STM32F405: 64 KB CCM + 128 KB SRAM)
//! [`MAX_VICTIMS`] = 4 slots (the front end tracks up to [`crate::frontend::MAX_TRACKS`]) of
//! [`VICTIM_CAPACITY`] = 80 components × 264 B: 84 480 B of components (320 in all).
//! The receiver application (≈ 88 KB with this bank) lives in SRAM on the board; the ADC
//! sample queue (32 KB) and the front end live in the 64 KB CCM instead, which leaves
//! ≥ 36 KB of SRAM for the stack (high-water ≈ 25 KB, `hal-sim/reports/reliability.md`).
//! Why 80 per victim (not 56, not one shared pool): `docs/decisions/component-pool.md`.
//! The re-association check runs on the stack with one copy of the motion pipeline and
//! no copy of a filter (`SogFilter::explains` is read-only).
//!
//! # Track identity and the list's capacity
//! A front end may give one transmitter several track ids (after a long overlap or
//! silence). A pulse of an unlisted source first goes to a listed victim silent for
//! [`REASSOCIATE_SILENT_S`] whose *localized* mixture explains it (the filter's own
//! outlier gate, IROS eq. 12–14, with that victim's pending motion), so its mixture and
//! mark carry over; only then does it take a free slot, the slot of a lost victim, or —
//! list full — the least useful one silent for [`EVICT_SILENT_S`] (marked first).
//! The three times, measured against their neighbours: `docs/decisions/victim-list-times.md`.

use crate::Vec3;
use crate::estimate::{
    Attitude, Displacement, EstimateError, Estimator, Pulse, SogConfig, SogFilter, StepReport,
};
use crate::frame::{Rpy, compose_rpy, rotation_from_rpy, rotation_partials};
use crate::motion::{Mat6, PdrNoise};

/// Victims followed at once (the front end may track more transmitters, see
/// [`crate::frontend::MAX_TRACKS`]; its dormant tracks keep their ids).
pub const MAX_VICTIMS: usize = 4;
/// Components per victim's mixture (four of them and the rest of the application fit
/// in SRAM beside a ≥ 36 KB stack; see the memory budget above).
pub const VICTIM_CAPACITY: usize = 80;
/// The per-victim filter.
pub type VictimSog = SogFilter<VICTIM_CAPACITY>;
/// An unmarked victim not heard for this long (s) is dropped from the list (its track
/// is lost: out of range or switched off). As long as the front end keeps a dormant
/// track's id ([`crate::frontend::DORMANT_S`]), so that it comes back to its mixture.
pub const LOST_S: f32 = crate::frontend::DORMANT_S;
/// A victim heard fewer times than this is a track that never got established (a
/// transmitter's first pulses before its track was re-attached, or pulses of several
/// transmitters briefly taken as one): it is dropped after [`SHORT_LOST_S`] of silence.
pub const FEW_PULSES: u32 = 5;
/// Silence (s) after which a victim of fewer than [`FEW_PULSES`] pulses is dropped: a
/// few of the longest periods, longer than the front end keeps an unconfirmed track.
pub const SHORT_LOST_S: f32 = 6.0;
/// A pulse withheld as an overlap within this time (s) keeps silent established victims
/// listed (several of the longest periods; `docs/decisions/overlap-thresholds.md`).
pub const OVERLAP_HOLD_S: f32 = 5.0;
/// A listed victim silent at least this long (s) may take a new front-end track whose
/// pulse its mixture explains ([`VictimBank::reassociate`]): longer than the longest
/// period of the standard (1.3 s), so it missed at least one of its own pulses.
pub const REASSOCIATE_SILENT_S: f32 = 1.5;
/// A victim's mixture must be localized to this fraction of its distance (σ_h / d, a
/// bearing known to about ±11°) before it may take a new track ([`VictimBank::reassociate`]).
pub const REASSOCIATE_SIGMA_FRACTION: f32 = 0.2;
/// With the list full, a victim silent at least this long (s) may be evicted for a new
/// transmitter ([`VictimBank::slot_for`]): several of the longest periods.
pub const EVICT_SILENT_S: f32 = 10.0;
/// Front-end sources of marked victims remembered after their slot was given away: as
/// many as the front end keeps tracks ([`crate::frontend::MAX_TRACKS`]), whose ids
/// outlive a victim's slot (dormant tracks, re-attachment).
pub const MARKED_SOURCES: usize = crate::frontend::MAX_TRACKS;

/// The composition `a ⊕ b` of two consecutive motions (IROS 2006 eq. 5–6): `a` from
/// `R_i` to `R_j`, `b` from `R_j` to `R_k`; the result goes from `R_i` to `R_k`.
///
/// Translation `t = t_a + R(Ψ_a) t_b`, rotation `Ψ = Ψ_a ⊕ Ψ_b`; the covariance is
/// `J_a Q_a J_aᵀ + J_b Q_b J_bᵀ` (the two intervals' errors are independent). The
/// absolute (unscaled) parts compose the same way: `s·t + abs` stays linear in `s`.
/// Returns `None` when the result is not finite.
pub fn compose(a: &Displacement, b: &Displacement) -> Option<Displacement> {
    let ra = rotation_from_rpy(&a.rotation);
    let (rot, ja_rot, jb_rot) = compose_rpy(&a.rotation, &b.rotation);
    let partials = rotation_partials(&a.rotation);
    // J_a = [[I, ∂(R_a t_b)/∂Ψ_a], [0, ∂Ψ/∂Ψ_a]],  J_b = [[R_a, 0], [0, ∂Ψ/∂Ψ_b]].
    let mut ja = Mat6::identity();
    let mut jb = Mat6::zeros();
    for (c, dr) in partials.iter().enumerate() {
        let col = dr * b.translation;
        ja.fixed_view_mut::<3, 1>(0, 3 + c).copy_from(&col);
    }
    ja.fixed_view_mut::<3, 3>(3, 3).copy_from(&ja_rot);
    jb.fixed_view_mut::<3, 3>(0, 0).copy_from(&ra);
    jb.fixed_view_mut::<3, 3>(3, 3).copy_from(&jb_rot);
    let cov = ja * a.cov * ja.transpose() + jb * b.cov * jb.transpose();
    let d = Displacement {
        translation: a.translation + ra * b.translation,
        rotation: rot,
        cov: (cov + cov.transpose()) * 0.5,
        absolute: a.absolute + ra * b.absolute,
        absolute_cov: a.absolute_cov + ra * b.absolute_cov * ra.transpose(),
    };
    let finite = d.translation.iter().all(|v| v.is_finite())
        && d.rotation.iter().all(|v| v.is_finite())
        && d.cov.iter().all(|v| v.is_finite())
        && d.absolute.iter().all(|v| v.is_finite())
        && d.absolute_cov.iter().all(|v| v.is_finite());
    finite.then_some(d)
}

/// The receiver's motion since a victim's last pulse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pending {
    /// The composed displacement.
    pub d: Displacement,
    /// Distance walked along the path, m.
    pub distance_m: f32,
    /// Steps detected in the cuts composed (for the interval floors).
    pub steps: u32,
    /// The walker stood through every cut composed.
    pub standing: bool,
}

impl Pending {
    /// No motion yet.
    pub fn zero() -> Self {
        Self {
            d: Displacement::zero(),
            distance_m: 0.0,
            steps: 0,
            standing: true,
        }
    }

    /// This motion followed by `next` (walking `distance_m`), or `None` if not finite.
    pub fn then(&self, next: &Displacement, distance_m: f32) -> Option<Self> {
        Some(Self {
            d: compose(&self.d, next)?,
            distance_m: self.distance_m + distance_m.max(0.0),
            ..*self
        })
    }

    /// This motion followed by the cut `m.cut` (its steps and standing counted).
    pub fn then_cut(&self, m: &MotionCut) -> Option<Self> {
        let mut p = self.then(&m.cut, m.distance_m)?;
        p.steps = p.steps.saturating_add(u32::from(m.steps));
        p.standing &= m.standing;
        Some(p)
    }

    /// This motion with the per-interval floors of `noise` added once for the whole
    /// interval (see [`crate::motion::Motion::take_split`]); `None` leaves it as is.
    pub fn with_floors(mut self, noise: Option<&PdrNoise>) -> Self {
        if let Some(n) = noise {
            self.d.cov += n.interval_floors(self.steps, self.standing);
        }
        self
    }
}

/// The receiver's motion at one pulse, split for several victims (see
/// [`crate::motion::Motion::take_split`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionCut {
    /// The motion since the previous pulse (of any victim), without the step in progress.
    pub cut: Displacement,
    /// The step in progress at the pulse (its own victim only).
    pub partial: Displacement,
    /// Its inverse: the start of the pulse's victim's next motion.
    pub back: Displacement,
    /// Distance walked since the previous pulse (without the step in progress), m.
    pub distance_m: f32,
    /// Length of the step in progress credited at the pulse, m.
    pub partial_m: f32,
    /// Steps detected in the cut.
    pub steps: u16,
    /// The walker stood through the cut.
    pub standing: bool,
    /// The per-interval floors to add once per victim interval (`None`: already in
    /// `cut`, a lone victim's whole interval from `take_displacement`).
    pub floors: Option<PdrNoise>,
}

/// One victim of the list.
#[derive(Debug, Clone)]
pub struct Victim {
    src: Option<u8>,
    filter: VictimSog,
    pending: Pending,
    last_t: f32,
    /// Attitude of the receiver at this victim's last pulse (to bring its estimate,
    /// relative to `R` then, to the present).
    rpy_last: Rpy,
    active: bool,
    marked: bool,
    pulses: u32,
}

impl Victim {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        self.last_t -= shift_s;
        self.filter.rebase(shift_s);
    }

    /// A free slot whose filter uses `cfg` (already checked by the bank).
    #[inline(always)]
    fn empty(cfg: SogConfig) -> Self {
        Self {
            src: None,
            filter: VictimSog::new_checked(cfg),
            pending: Pending::zero(),
            last_t: 0.0,
            rpy_last: Rpy::zeros(),
            active: false,
            marked: false,
            pulses: 0,
        }
    }

    /// The front-end source of this victim (`None`: logs without source attribution).
    pub fn src(&self) -> Option<u8> {
        self.src
    }

    /// Whether pulses of `src` are this victim's.
    pub fn has_src(&self, src: Option<u8>) -> bool {
        self.active && self.src == src
    }

    /// Whether its mixture is localized enough to tell its transmitter's pulses from
    /// another's: horizontal σ (√ of the covariance's horizontal trace) within
    /// [`REASSOCIATE_SIGMA_FRACTION`] of its horizontal distance. A broad mixture (early
    /// flux-line phase) explains a pulse from anywhere around.
    fn localized(&self) -> bool {
        self.filter.estimate().is_some_and(|e| {
            let sigma = libm::sqrtf((e.cov.m11 + e.cov.m22).max(0.0));
            sigma <= REASSOCIATE_SIGMA_FRACTION * e.p.xy().norm()
        })
    }

    /// This victim's mixture.
    pub fn filter(&self) -> &VictimSog {
        &self.filter
    }

    /// Whether the rescuer marked this victim as found.
    pub fn marked(&self) -> bool {
        self.marked
    }

    /// Pulses of this victim accepted so far.
    pub fn pulses(&self) -> u32 {
        self.pulses
    }

    /// Time of this victim's last pulse, s.
    pub fn last_t(&self) -> f32 {
        self.last_t
    }

    /// The motion since this victim's last pulse.
    pub fn pending(&self) -> &Pending {
        &self.pending
    }

    /// The victim's position relative to the receiver *now* (m, north/west/up): its
    /// estimate at its last pulse minus the scaled motion since (IROS eq. 5 applied to
    /// the mean only). `None` before its mixture is initialized.
    pub fn position_now(&self) -> Option<Vec3> {
        self.position_moved(&self.pending.d.translation, &self.pending.d.absolute)
    }

    /// [`Victim::position_now`] carried further over `more`, the motion since the last
    /// cut of the running interval (peeked from the motion pipeline between pulses): where
    /// to point while no pulse comes. The means of IROS eq. 5 only: pointing needs no
    /// covariance. `None` before its mixture is initialized.
    pub fn position_after(&self, more: &Displacement) -> Option<Vec3> {
        let d = &self.pending.d;
        let rd = rotation_from_rpy(&d.rotation);
        let translation = d.translation + rd * more.translation;
        let absolute = d.absolute + rd * more.absolute;
        self.position_moved(&translation, &absolute)
    }

    /// The estimate minus the motion (`translation` scaled by the estimated scale, plus
    /// the `absolute` part) in the receiver's axes at this victim's last pulse.
    fn position_moved(&self, translation: &Vec3, absolute: &Vec3) -> Option<Vec3> {
        let e = self.filter.estimate()?;
        let r = rotation_from_rpy(&self.rpy_last);
        let p = e.p - r * (translation * e.scale + absolute);
        p.iter().all(|v| v.is_finite()).then_some(p)
    }
}

/// The fixed set of victim slots (see the module docs for the memory budget).
#[derive(Debug, Clone)]
pub struct VictimBank {
    slots: [Victim; MAX_VICTIMS],
    /// Time of the last pulse the front end withheld as an overlap (s).
    withheld_t: f32,
    /// Sources of victims the rescuer marked, most recent last (see
    /// [`VictimBank::step`]: a marked victim's transmitter heard again after its slot
    /// was evicted comes back marked, not as a new victim to search for).
    marked_srcs: heapless::Deque<u8, MARKED_SOURCES>,
}

impl VictimBank {
    /// Moves every stored time stamp `shift_s` s earlier: the clock's epoch moved that
    /// much later ([`crate::timebase::Epoch`]); durations are left as they are.
    pub fn rebase(&mut self, shift_s: f32) {
        self.withheld_t -= shift_s;
        for v in &mut self.slots {
            v.rebase(shift_s);
        }
    }

    /// An empty bank whose filters use `cfg`, or `InvalidConfig`.
    pub fn new(cfg: SogConfig) -> Result<Self, EstimateError> {
        VictimSog::check_config(&cfg)?;
        Ok(Self::new_checked(cfg))
    }

    /// [`VictimBank::new`] for a configuration the filter accepted: infallible and built
    /// slot by slot, so the ≈ 85 KB bank can be built in its final place (see
    /// [`crate::app::Receiver::emplace`]) without a whole copy on the stack.
    #[inline(always)]
    pub(crate) fn new_checked(cfg: SogConfig) -> Self {
        // An array literal of element constructors (not `from_fn` or clones, which build
        // each ≈ 21 KB element on the stack and copy it): the compiler writes each field
        // straight into the destination.
        Self {
            slots: [
                Victim::empty(cfg),
                Victim::empty(cfg),
                Victim::empty(cfg),
                Victim::empty(cfg),
            ],
            withheld_t: f32::NEG_INFINITY,
            marked_srcs: heapless::Deque::new(),
        }
    }

    /// The front end withheld a pulse at `t` (s; overlapping transmitters): an
    /// established victim is not dropped as lost while pulses are being withheld (its
    /// own may be among them: two trains of nearly equal periods overlap for minutes).
    pub fn note_withheld(&mut self, t: f32) {
        if t.is_finite() {
            self.withheld_t = self.withheld_t.max(t);
        }
    }

    /// The receiver's tracked height above the snow (m) for every filter's next
    /// initialization (see [`VictimSog::set_receiver_height`]).
    pub fn set_receiver_height(&mut self, height_m: f32) {
        for v in self.slots.iter_mut() {
            v.filter.set_receiver_height(height_m);
        }
    }

    /// Empties every slot.
    pub fn reset(&mut self) {
        for v in self.slots.iter_mut() {
            v.filter.reset();
            v.pending = Pending::zero();
            v.active = false;
            v.marked = false;
            v.pulses = 0;
        }
        self.withheld_t = f32::NEG_INFINITY;
        self.marked_srcs.clear();
    }

    /// The slots that hold a victim, with their slot index (the list number − 1).
    pub fn active(&self) -> impl Iterator<Item = (usize, &Victim)> + '_ {
        self.slots.iter().enumerate().filter(|(_, v)| v.active)
    }

    /// Number of victims in the list.
    pub fn len(&self) -> usize {
        self.active().count()
    }

    /// Whether the list is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The filter of slot `i` (empty when the slot is free; slot 0's for a bad index).
    pub fn filter(&self, i: usize) -> &VictimSog {
        let v = self.slots.get(i).unwrap_or(&self.slots[0]);
        &v.filter
    }

    /// The victim in slot `i`, if any.
    pub fn get(&self, i: usize) -> Option<&Victim> {
        self.slots.get(i).filter(|v| v.active)
    }

    /// The slot of the victim whose pulses `src` are, if listed.
    pub fn slot_of(&self, src: Option<u8>) -> Option<usize> {
        self.slots.iter().position(|v| v.has_src(src))
    }

    /// The slot for a pulse of `src` at `t`: its victim's, else a free one (a slot whose
    /// unmarked victim was silent for [`LOST_S`] is free again), else the least useful
    /// victim silent for [`EVICT_SILENT_S`]: marked ones first (found: their mixture is
    /// no longer needed), then the one of fewest pulses. `None`: every victim is needed.
    pub fn slot_for(&self, src: Option<u8>, t: f32) -> Option<usize> {
        if let Some(i) = self.slot_of(src) {
            return Some(i);
        }
        self.slots
            .iter()
            .position(|v| !v.active)
            .or_else(|| self.slots.iter().position(|v| self.lost(v, t)))
            .or_else(|| {
                self.slots
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| t - v.last_t >= EVICT_SILENT_S)
                    .min_by_key(|(_, v)| (!v.marked, v.pulses))
                    .map(|(i, _)| i)
            })
    }

    /// A pulse of a source not in the list: the victim silent for at least
    /// [`REASSOCIATE_SILENT_S`] whose mixture explains it (the filter's outlier gate,
    /// with the motion since that victim's last pulse composed as [`VictimBank::step`]
    /// would) takes `src` — the front end gave its transmitter a new track id (after a
    /// long overlap or silence). Only a localized mixture qualifies (see
    /// `Victim::localized`); among several, the one of most pulses. Returns its slot.
    /// Read-only but for the relabelling.
    pub fn reassociate(
        &mut self,
        src: Option<u8>,
        m: &MotionCut,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Option<usize> {
        if src.is_none() || self.slot_of(src).is_some() {
            return None;
        }
        let mut best: Option<(usize, u32)> = None;
        for (i, v) in self.slots.iter().enumerate() {
            if !v.active || pulse.t - v.last_t < REASSOCIATE_SILENT_S || !v.localized() {
                continue;
            }
            let Some(own) = v
                .pending
                .then_cut(m)
                .and_then(|p| p.then(&m.partial, m.partial_m))
                .map(|p| p.with_floors(m.floors.as_ref()))
            else {
                continue;
            };
            if v.filter.explains(&own.d, attitude, pulse) == Some(true)
                && best.is_none_or(|(_, n)| v.pulses > n)
            {
                best = Some((i, v.pulses));
            }
        }
        let (i, _) = best?;
        let v = self.slots.get_mut(i)?;
        v.src = src;
        if v.marked {
            self.remember_marked(src);
        }
        Some(i)
    }

    /// Remembers `src` as a marked victim's source (the oldest is forgotten when full).
    fn remember_marked(&mut self, src: Option<u8>) {
        let Some(s) = src else { return };
        if self.marked_srcs.iter().any(|m| *m == s) {
            return;
        }
        if self.marked_srcs.is_full() {
            self.marked_srcs.pop_front();
        }
        let _ = self.marked_srcs.push_back(s);
    }

    /// Whether `src` is the source of a victim the rescuer marked.
    pub fn was_marked(&self, src: Option<u8>) -> bool {
        src.is_some_and(|s| self.marked_srcs.iter().any(|m| *m == s))
    }

    fn lost(&self, v: &Victim, t: f32) -> bool {
        let silent = t - v.last_t;
        let overlapping = t - self.withheld_t <= OVERLAP_HOLD_S;
        v.active
            && !v.marked
            && ((silent > LOST_S && !overlapping)
                || (v.pulses < FEW_PULSES && silent > SHORT_LOST_S))
    }

    /// Drops the unmarked victims not heard since `t − LOST_S` (`t − SHORT_LOST_S` for
    /// those of few pulses); returns how many.
    pub fn drop_lost(&mut self, t: f32) -> usize {
        let mut n = 0;
        for i in 0..MAX_VICTIMS {
            if let Some(v) = self.slots.get(i)
                && self.lost(v, t)
                && let Some(v) = self.slots.get_mut(i)
            {
                v.active = false;
                n += 1;
            }
        }
        n
    }

    /// One pulse of `src` in slot `i` (from [`VictimBank::slot_for`]): the motion cut
    /// at this pulse (`m.cut`, see [`crate::motion::Motion::take_split`]) is composed onto
    /// every victim's pending motion, slot `i`'s filter steps with its own followed by
    /// the step in progress (`m.partial`), and its pending motion restarts from
    /// `m.back`. On error nothing changes (except that a free slot taken for a new victim
    /// stays free and empty). Returns the step's report and the pending motion the victim
    /// was stepped with.
    pub fn step(
        &mut self,
        i: usize,
        src: Option<u8>,
        m: &MotionCut,
        attitude: &Attitude,
        pulse: &Pulse,
    ) -> Result<(StepReport, Pending), EstimateError> {
        let mut pend = [Pending::zero(); MAX_VICTIMS];
        for (p, v) in pend.iter_mut().zip(self.slots.iter()) {
            if v.active {
                *p = v.pending.then_cut(m).ok_or(EstimateError::OutOfRange)?;
            }
        }
        let slot = self.slots.get(i).ok_or(EstimateError::InvalidConfig)?;
        let fresh_victim = !slot.has_src(src);
        // A new victim's motion before its first pulse does not matter (a fresh mixture).
        let before = if fresh_victim {
            Pending::zero()
        } else {
            pend.get(i).copied().ok_or(EstimateError::InvalidConfig)?
        };
        // The own victim's interval gets its floors once (see `MotionCut::floors`).
        let own = before
            .then(&m.partial, m.partial_m)
            .ok_or(EstimateError::OutOfRange)?
            .with_floors(m.floors.as_ref());
        let back = Pending {
            d: m.back,
            distance_m: -m.partial_m,
            ..Pending::zero()
        };
        let slot = self.slots.get_mut(i).ok_or(EstimateError::InvalidConfig)?;
        if fresh_victim {
            // A new victim (or a lost one's slot taken over): a fresh mixture, reset in
            // place (a copy of the ≈ 21 KB filter would not fit the board's stack). The
            // slot was free (`slot_for`), so a refused first pulse leaves it free.
            slot.active = false;
            slot.filter.reset();
            let report = slot.filter.step(&own.d, attitude, pulse)?;
            // A marked victim's transmitter heard again after its slot was given away
            // (list full, `slot_for`): the front end kept its id, so it is the victim
            // already found, listed again as marked (else it is searched for and marked
            // a second time: a wrong-victim mark of `multi-report`).
            let marked = src.is_some_and(|s| self.marked_srcs.iter().any(|m| *m == s));
            let Some(slot) = self.slots.get_mut(i) else {
                return Err(EstimateError::InvalidConfig);
            };
            slot.src = src;
            slot.marked = marked;
            slot.pulses = 0;
            slot.active = true;
            return Ok(self.commit(i, pend, back, attitude, pulse.t, report, own));
        }
        let report = slot.filter.step(&own.d, attitude, pulse)?;
        Ok(self.commit(i, pend, back, attitude, pulse.t, report, own))
    }

    #[allow(clippy::too_many_arguments)] // private: the parts of one step, kept apart
    fn commit(
        &mut self,
        i: usize,
        pend: [Pending; MAX_VICTIMS],
        back: Pending,
        attitude: &Attitude,
        t: f32,
        report: StepReport,
        own: Pending,
    ) -> (StepReport, Pending) {
        for (j, (v, p)) in self.slots.iter_mut().zip(pend).enumerate() {
            if j == i {
                v.pending = back;
                v.last_t = t;
                v.rpy_last = attitude.rpy;
                v.pulses = v.pulses.saturating_add(1);
            } else if v.active {
                v.pending = p;
            }
        }
        (report, own)
    }

    /// Marks the victim in slot `i` as found; `false` if there is none.
    pub fn mark(&mut self, i: usize) -> bool {
        match self.slots.get_mut(i) {
            Some(v) if v.active => {
                v.marked = true;
                let src = v.src;
                self.remember_marked(src);
                true
            }
            _ => false,
        }
    }

    /// The nearest unmarked victim (horizontal distance now) with an estimate.
    pub fn nearest_unmarked(&self) -> Option<(usize, f32)> {
        self.nearest_unmarked_heard_since(f32::NEG_INFINITY)
    }

    /// The nearest unmarked victim with an estimate heard at or after `since` (s).
    pub fn nearest_unmarked_heard_since(&self, since: f32) -> Option<(usize, f32)> {
        self.active()
            .filter(|(_, v)| !v.marked && v.last_t >= since)
            .filter_map(|(i, v)| v.position_now().map(|p| (i, p.xy().norm())))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }
}

#[cfg(test)]
#[path = "victims_tests.rs"]
mod tests;
