//! The menu's two procedures, run by the board while the menu is open
//! ([`crate::board::menu::MenuEvent::Start`]):
//!
//! - **Step walk**: the rescuer walks [`WALK_DISTANCE_M`] at normal pace from the long
//!   press that starts it to a press of the mark button; step length = distance / steps
//!   counted by the dead reckoning ([`crate::motion::Motion::total_steps`],
//!   [`StepCalibration`]'s checks: at least 10 steps, a length within the step model's
//!   range).
//! - **Magnetometer calibration**: the rescuer turns the receiver through every
//!   orientation in one place (upside down and on its sides too) until the mark button;
//!   every raw magnetometer reading goes to the ellipsoid fit
//!   ([`MagCalibrator`], the region's field magnitude as its scale).
//!
//! The sound button (short press) cancels. A result goes into the menu's copy of the
//! settings ([`apply`]), so leaving the menu stores it; a failure is shown with its reason
//! and changes nothing.

use crate::Vec3;
use crate::board::menu::Procedure;
use crate::board::settings::Settings;
use crate::calibration::mag::{MagCalibrator, MagFit, MagFitError};
use crate::motion::MotionError;
use crate::motion::steps::StepCalibration;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::{FONT_6X10, FONT_10X20};
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};

/// The distance of the step walk, m: long enough for ≈ 30 steps (the step length to
/// ≈ 1/30 from the step count's ±1), short enough to pace out on a trailhead (20 m is
/// also what the calibration walk of the motion tests uses).
pub const WALK_DISTANCE_M: f32 = 20.0;

/// A procedure in progress.
// No heap to box the accumulator into; the one instance lives in the processing task.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum Running {
    /// The step walk, from this step count.
    StepWalk {
        /// Steps counted when it started.
        start_steps: u32,
    },
    /// The magnetometer calibration's accumulator.
    MagCal(MagCalibrator),
}

/// How a procedure ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome {
    /// The step walk's step length, m, and the steps counted.
    StepLength {
        /// Step length, m.
        length_m: f32,
        /// Steps counted over the walk.
        steps: u32,
    },
    /// The magnetometer calibration.
    Mag(MagFit),
    /// The step walk failed (too few steps, an implausible length).
    WalkFailed(MotionError),
    /// The magnetometer fit failed (too few readings, poor coverage, no ellipsoid).
    MagFailed(MagFitError),
}

impl Outcome {
    /// The display's (and the log's) word for it.
    pub fn word(&self) -> &'static str {
        match self {
            Outcome::StepLength { .. } | Outcome::Mag(_) => "done",
            Outcome::WalkFailed(MotionError::TooFewSteps { .. }) => "too few steps",
            Outcome::WalkFailed(_) => "bad length",
            Outcome::MagFailed(MagFitError::TooFewSamples) => "too few",
            Outcome::MagFailed(MagFitError::PoorCoverage) => "turn more",
            Outcome::MagFailed(_) => "disturbed",
        }
    }
}

impl Running {
    /// Starts `p`: the step walk at `total_steps` steps counted so far, the magnetometer
    /// calibration for an earth field of `field_ut` µT (the region's).
    pub fn start(p: Procedure, total_steps: u32, field_ut: f32) -> Result<Running, MagFitError> {
        Ok(match p {
            Procedure::StepWalk => Running::StepWalk {
                start_steps: total_steps,
            },
            Procedure::MagCalibration => Running::MagCal(MagCalibrator::new(field_ut)?),
        })
    }

    /// Which procedure this is.
    pub fn procedure(&self) -> Procedure {
        match self {
            Running::StepWalk { .. } => Procedure::StepWalk,
            Running::MagCal(_) => Procedure::MagCalibration,
        }
    }

    /// A raw (uncalibrated) magnetometer reading, µT: used by the calibration only; a
    /// non-finite one is skipped.
    pub fn on_mag(&mut self, raw: &Vec3) {
        if let Running::MagCal(c) = self {
            // Refused readings are not accumulated: nothing else to do with them.
            let _skipped = c.push(raw);
        }
    }

    /// Progress for the display: steps walked, or readings taken.
    pub fn progress(&self, total_steps: u32) -> u32 {
        match self {
            Running::StepWalk { start_steps } => total_steps.saturating_sub(*start_steps),
            Running::MagCal(c) => c.samples(),
        }
    }

    /// The mark button ends it: the result at `total_steps` steps counted.
    pub fn finish(&self, total_steps: u32) -> Outcome {
        match self {
            Running::StepWalk { start_steps } => {
                // The Weinberg sums are not used for the step length (the motion keeps
                // them private): zero at both ends.
                match StepCalibration::start(*start_steps, 0.0).finish(
                    total_steps,
                    0.0,
                    WALK_DISTANCE_M,
                ) {
                    Ok(r) => Outcome::StepLength {
                        length_m: r.step_length_m,
                        steps: r.steps,
                    },
                    Err(e) => Outcome::WalkFailed(e),
                }
            }
            Running::MagCal(c) => match c.fit() {
                Ok(fit) => Outcome::Mag(fit),
                Err(e) => Outcome::MagFailed(e),
            },
        }
    }
}

/// Puts a procedure's result into `settings` (their calibration record); false when the
/// procedure failed and nothing changed.
pub fn apply(outcome: &Outcome, settings: &mut Settings) -> bool {
    match outcome {
        Outcome::StepLength { length_m, .. } => {
            settings.calibration.step_length_m = Some(*length_m);
            true
        }
        Outcome::Mag(fit) => {
            settings.calibration.mag = Some(fit.calibration);
            true
        }
        Outcome::WalkFailed(_) | Outcome::MagFailed(_) => false,
    }
}

/// Draws a running procedure over a cleared `target`: what to do, the progress, what the
/// buttons do.
pub fn draw<D: DrawTarget<Color = BinaryColor>>(
    p: Procedure,
    progress: u32,
    target: &mut D,
) -> Result<(), D::Error> {
    let small = MonoTextStyle::new(&FONT_6X10, BinaryColor::On);
    let large = MonoTextStyle::new(&FONT_10X20, BinaryColor::On);
    let (title, unit) = match p {
        Procedure::StepWalk => ("WALK 20 M, NORMAL PACE", "STEPS"),
        Procedure::MagCalibration => ("TURN IN ALL DIRECTIONS", "READ"),
    };
    let mut buf = heapless::String::<16>::new();
    // Ten digits and a unit fit in 16 bytes: the write cannot fail.
    let _fits = core::fmt::write(&mut buf, format_args!("{progress} {unit}"));
    Text::with_baseline(title, Point::new(0, 0), small, Baseline::Top).draw(target)?;
    Text::with_baseline(&buf, Point::new(0, 18), large, Baseline::Top).draw(target)?;
    Text::with_baseline(
        "D6 done  D12 cancel",
        Point::new(0, 54),
        small,
        Baseline::Top,
    )
    .draw(target)?;
    Ok(())
}

/// Draws how a procedure ended (shown until the next button press).
pub fn draw_outcome<D: DrawTarget<Color = BinaryColor>>(
    outcome: &Outcome,
    target: &mut D,
) -> Result<(), D::Error> {
    let small = MonoTextStyle::new(&FONT_6X10, BinaryColor::On);
    let large = MonoTextStyle::new(&FONT_10X20, BinaryColor::On);
    let mut buf = heapless::String::<24>::new();
    let _fits = match outcome {
        Outcome::StepLength { length_m, steps } => {
            core::fmt::write(&mut buf, format_args!("{:.2} M/{steps}", length_m))
        }
        Outcome::Mag(fit) => {
            core::fmt::write(&mut buf, format_args!("{:.1} UT RMS", fit.residual_rms_ut))
        }
        _ => core::fmt::write(&mut buf, format_args!("FAILED")),
    };
    Text::with_baseline(outcome.word(), Point::new(0, 0), small, Baseline::Top).draw(target)?;
    Text::with_baseline(&buf, Point::new(0, 18), large, Baseline::Top).draw(target)?;
    Ok(())
}

#[cfg(test)]
#[path = "procedure_tests.rs"]
mod tests;
