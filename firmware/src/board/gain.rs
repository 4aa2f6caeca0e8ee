//! Gain ranging on the board: the front end's [`RangeChange`] applied to the hardware
//! (the PGA gain of the three coil channels, the IF range switch) and handed on as the
//! session log's `gain` event ([`crate::board::board_log::BoardLog::gain`]), so that a
//! replay knows in which analog setting every later pulse was measured and why the
//! setting moved.
//!
//! The hardware write is the caller's closure (the board binary's register write under
//! the DRDY task's lock); what happens around it — the front end put back on the old
//! setting when the write failed, the samples already queued in the old setting discarded
//! with the switch's settling, the event's time stamp — is here, tested on the host.

use crate::frontend::{Frontend, IfRange, Range, RangeChange, RangeReason};
use crate::timebase::Instant;

/// A change of the analog setting as the board applied it: one `gain` event.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GainEvent {
    /// Board time of the first sample taken in the new setting, µs since boot (the same
    /// clock as the log's pulse times: the DSP's sample index plus the stalled time).
    pub t_us: u64,
    /// What the front end asked for.
    pub change: RangeChange,
    /// False when the PGA write failed: the hardware and the DSP stay at `change.from`.
    pub applied: bool,
}

impl GainEvent {
    /// The setting in use from this event on.
    pub fn now_in(&self) -> Range {
        if self.applied {
            self.change.to
        } else {
            self.change.from
        }
    }
}

/// The log's word for why the setting changed.
pub fn reason_word(r: RangeReason) -> &'static str {
    match r {
        RangeReason::Saturated => "saturated",
        RangeReason::Strong => "strong",
        RangeReason::Weak => "weak",
    }
}

/// The log's word for the IF range switch.
pub fn if_word(r: IfRange) -> &'static str {
    match r {
        IfRange::High => "high",
        IfRange::Low => "low",
    }
}

/// Takes the front end's pending change of setting, if any, and applies it: `write`
/// sets the hardware to the change's `to` and returns whether the PGA took it (when it
/// returns false it must leave the IF switch at `from`); on failure the front end is put
/// back on `from`. Either way the `queued` samples still waiting in the sample queue
/// (taken in the old setting) are discarded with the settling. `offset_us` is the time
/// the DSP did not see (`SampleClock::offset_us`), `rate_hz` its sample rate.
pub fn apply_change(
    fe: &mut Frontend,
    queued: usize,
    rate_hz: f32,
    offset_us: u64,
    write: impl FnOnce(&RangeChange) -> bool,
) -> Option<GainEvent> {
    let change = fe.take_range_change()?;
    // The change takes effect from the next sample the DSP is fed (its index is the
    // count consumed so far).
    let t_us = sample_us(fe.samples(), rate_hz).saturating_add(offset_us);
    let applied = write(&change);
    if !applied {
        // The DSP already switched: back to what the hardware still measures in. The old
        // setting came from the ladder, so this cannot be refused; if it were, the DSP
        // would calibrate for the wrong setting, hence the check in the tests.
        let _on_ladder = fe.set_range(change.from);
    }
    fe.extend_settle(queued);
    Some(GainEvent {
        t_us,
        change,
        applied,
    })
}

/// Time of sample `index` at `rate_hz`, whole µs (as the pulse times:
/// [`crate::timebase::pulse_centre_us`]); 0 for a rate that is not finite and positive.
fn sample_us(index: u64, rate_hz: f32) -> u64 {
    Instant::from_secs_f64(index as f64 / f64::from(rate_hz)).map_or(0, Instant::micros)
}

#[cfg(test)]
#[path = "gain_tests.rs"]
mod tests;
