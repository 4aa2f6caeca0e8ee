//! What the screen shows: the display model the application fills and the renderer draws.

use crate::guidance::classic::ClassicScreen;
use crate::guidance::{HeightPrompt, Status};
use crate::victims::MAX_VICTIMS;

/// Everything the display shows (the screen draws only this, see [`crate::display`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DisplayModel {
    /// Status word.
    pub status: Status,
    /// Arrow relative to the device's current heading, degrees, positive to the left, in
    /// (-180, 180]; `None`: no direction to show.
    pub arrow_deg: Option<f32>,
    /// Straight-line (3-D) distance to the victim estimate, m.
    pub distance_m: Option<f32>,
    /// Horizontal distance to the victim estimate, m.
    pub horizontal_m: Option<f32>,
    /// Burial depth below the snow surface, m (fine search only).
    pub depth_m: Option<f32>,
    /// Horizontal distance to walk along the arrow, m (to the estimate, or to the
    /// bracketing point beside it in the fine search); 0 when probing.
    pub walk_m: Option<f32>,
    /// Uncertainty of the victim's horizontal position: largest horizontal σ, m.
    pub uncertainty_m: Option<f32>,
    /// Transmitters heard (distinct front-end sources; 1 without source attribution).
    pub victims: u8,
    /// The last pulse was withheld by the front end (overlapping transmitters, clipping).
    pub overlap: bool,
    /// Pulses processed so far (a new value means a new estimate).
    pub pulses: u32,
    /// Time of the pulse the guidance shown comes from, s since boot (the session log's
    /// clock): the target victim's last pulse (another victim's pulse does not renew the
    /// target's prompt; a rescuer who stood still waits for a time after it), else the
    /// last pulse.
    pub t_s: f64,
    /// Fine search: "LIFT" — stand and lift the receiver ≈ 0.4 m and lower it within
    /// ~2 s (an absolute vertical displacement that pins the depth); steps are not
    /// counted meanwhile.
    pub lift: bool,
    /// Fine search: lower the receiver to the snow, or raise it again (stand meanwhile;
    /// steps are not counted while it shows).
    pub height_prompt: HeightPrompt,
    /// The receiver's height above the snow as tracked (m): the configured height plus
    /// the vertical moves the accelerometer measured (`app::Receiver::height_m`).
    pub height_m: f32,
    /// The victim list, by list number (slot); `None`: free slot.
    pub list: [Option<VictimRow>; MAX_VICTIMS],
    /// List number (1-based) of the victim the guidance leads to.
    pub target: Option<u8>,
    /// Victims marked as found.
    pub found: u8,
}

/// The classic mode's screen as the display model: one transmitter at most, no estimate.
impl From<ClassicScreen> for DisplayModel {
    fn from(c: ClassicScreen) -> Self {
        Self {
            status: c.status,
            arrow_deg: c.arrow_deg,
            distance_m: c.distance_m,
            walk_m: c.walk_m,
            victims: u8::from(c.pulses > 0),
            pulses: c.pulses,
            // Seconds from the receiver's epoch: the receiver puts it on its clock.
            t_s: f64::from(c.t_s),
            ..Self::default()
        }
    }
}

/// One line of the victim list.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VictimRow {
    /// List number, 1-based.
    pub number: u8,
    /// Horizontal distance to the victim's estimate now, m (`None` before its mixture
    /// is initialized).
    pub distance_m: Option<f32>,
    /// Direction to it relative to the device's heading, degrees, positive left.
    pub arrow_deg: Option<f32>,
    /// Marked as found.
    pub marked: bool,
    /// The guidance leads to this one.
    pub target: bool,
}
