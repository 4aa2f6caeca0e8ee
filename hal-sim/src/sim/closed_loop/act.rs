//! What the simulated rescuer does at each tick: the primary search, the directional search's
//! commands, following the display and its height prompts.

use super::*;

/// Primary search: straight on along `heading` (with the rescuer's heading error), or
/// stand when there is none.
pub(crate) fn walk_primary(person: &mut Person, heading: Option<f64>, heading_err: f64) {
    match heading {
        Some(h) => {
            person.psi_des = h + heading_err;
            person.w_target = 1.0;
        }
        None => person.w_target = 0.0,
    }
}

/// Applies a directional-search command to the rescuer.
pub(super) fn apply_ds(cmd: Option<DsCommand>, person: &mut Person) {
    match cmd {
        Some(DsCommand::Heading { psi, walk }) => {
            person.psi_des = psi;
            person.w_target = if walk { 1.0 } else { 0.0 };
        }
        Some(DsCommand::MoveTo { xy, height }) => {
            person.crawl_to = Some(xy);
            if let Some(h) = height {
                person.hold_height = h;
            }
        }
        None => {}
    }
}

/// What the directional search sees of the rescuer.
pub(super) fn ds_view(person: &Person) -> RescuerView {
    RescuerView {
        device_xy: person.device_xy(),
        heading: person.psi,
    }
}

/// The rescuer's reaction to what they saw.
pub(crate) fn act(
    cfg: &ClosedLoopConfig,
    person: &mut Person,
    plan: &mut StepPlan,
    view: &Seen,
    heading_err: f64,
    t: f64,
) {
    let d = &view.display;
    if height_prompt(person, plan, d, t) {
        return;
    }
    // A lift under way: stand until it is over.
    if let Some(t0) = person.lift_t0 {
        person.w_target = 0.0;
        plan.lift_pulse = plan.lift_pulse.max(d.pulses);
        if t < t0 + LIFT_S {
            return;
        }
        person.lift_t0 = None;
        plan.stopped_at = t;
    }
    // "LIFT": stand, then lift the receiver up and down (once per new prompt).
    if d.lift {
        person.w_target = 0.0;
        plan.end_phase = None;
        if d.pulses > plan.lift_pulse && person.w < 1e-3 && person.crawl_to.is_none() {
            person.lift_t0 = Some(t);
            plan.lift_pulse = d.pulses;
            plan.lifts += 1;
        }
        plan.stopped_at = t;
        return;
    }
    let Some(arrow) = d.arrow_deg else {
        // Nothing to follow: stand (before the first signal) or keep going; when the
        // signal is lost, turn back once (toward where it was last heard).
        if d.pulses == 0 {
            person.w_target = 0.0;
        } else if d.status == Status::NoSignal && !plan.turned_back {
            plan.turned_back = true;
            person.psi_des = person.psi + PI;
            person.w_target = 0.0;
        } else {
            let off = wrap_pi(person.psi_des - person.psi).abs();
            person.w_target = if off > 0.9 { 0.0 } else { 1.0 };
        }
        return;
    };
    plan.turned_back = false;
    let desired = view.psi + f64::from(arrow).to_radians() + heading_err;
    // Near the shown point the walk goes step by step, also to a silent victim's estimate
    // (shown under "no signal").
    let fine = matches!(d.status, Status::Localized | Status::NoSignal)
        && d.walk_m.is_some_and(|w| f64::from(w) < cfg.fine_walk_m);
    if !fine {
        plan.end_phase = None;
        person.psi_des = desired;
        // Far off the arrow: stop and turn on the spot.
        let off = wrap_pi(desired - person.psi).abs();
        person.w_target = if off > 0.9 { 0.0 } else { 1.0 };
        return;
    }
    // Fine search, step by step.
    if let Some(end) = plan.end_phase {
        let turning = wrap_pi(person.psi_des - person.psi).abs() > 0.15;
        person.w_target = if turning || person.phase >= end - 0.27 {
            0.0
        } else {
            1.0
        };
        if person.phase >= end - 0.27 && person.w < 0.05 {
            plan.end_phase = None;
            plan.stopped_at = t;
        }
        return;
    }
    person.w_target = 0.0;
    if person.w > 1e-3 {
        // Not yet standing.
        plan.stopped_at = t;
        return;
    }
    // A display update taken after standing still: plan the next steps.
    if d.pulses > plan.acted_pulse && d.t_s > plan.stopped_at {
        plan.acted_pulse = d.pulses;
        let walk = f64::from(d.walk_m.unwrap_or(0.0));
        let n = (walk / cfg.step_length_m).round().min(3.0);
        if n >= 1.0 {
            person.psi_des = desired;
            plan.end_phase = Some(person.phase + n);
        }
    }
}

/// "LOWER TO SNOW" / "RAISE TO 1M": stop, pause [`SETTLE_S`] at rest, then move the
/// receiver to the asked height over [`HEIGHT_MOVE_S`]. Returns whether the rescuer is
/// busy with it (stands).
pub(super) fn height_prompt(
    person: &mut Person,
    plan: &mut StepPlan,
    d: &DisplayModel,
    t: f64,
) -> bool {
    if let Some((t0, _, to)) = person.height_move {
        person.w_target = 0.0;
        if t < t0 + HEIGHT_MOVE_S {
            return true;
        }
        person.hold_height = to;
        person.height_move = None;
        plan.stopped_at = t;
    }
    let to = match d.height_prompt {
        HeightPrompt::None => return false,
        HeightPrompt::Lower => LOW_HOLD_M,
        HeightPrompt::Raise => HOLD_HEIGHT_M,
    };
    person.w_target = 0.0;
    plan.end_phase = None;
    plan.stopped_at = plan.stopped_at.max(t - person.still_s);
    // A lift under way is finished first.
    if person.lift_t0.is_some_and(|t0| t >= t0 + LIFT_S) {
        person.lift_t0 = None;
    }
    if person.still_s >= SETTLE_S
        && person.crawl_to.is_none()
        && person.lift_t0.is_none()
        && (to - person.hold_height).abs() > 0.1
    {
        person.height_move = Some((t, person.hold_height, to));
        plan.height_moves += 1;
    }
    true
}

pub(super) fn snapshot(rx: &Receiver, t: f64, rx_p: &V3, status: Status) -> Snapshot {
    let components = rx
        .filter()
        .components()
        .map(|(w, p, c)| {
            (
                f64::from(w),
                [rx_p.x + f64::from(p.x), rx_p.y + f64::from(p.y)],
                [
                    f64::from(c[(0, 0)]),
                    f64::from(c[(0, 1)]),
                    f64::from(c[(1, 1)]),
                ],
            )
        })
        .collect();
    Snapshot {
        t,
        rx: [rx_p.x, rx_p.y],
        components,
        status: status.as_str(),
    }
}
