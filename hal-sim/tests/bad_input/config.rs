//! Cases of `receiver.json`, of many warnings and `inspect`, and of paths.

use super::*;

/// The cases of this group.
pub(super) fn cases() -> Vec<Case> {
    vec![
        // --- receiver.json ---------------------------------------------------------------------
        Case {
            name: "receiver.json: step length 10 m",
            receiver: Some(r#"{"pdr":{"step_length_m":10}}"#),
            stderr: &["pdr.step_length_m = 10 is outside [0.2, 1.5] m"],
            ..FAIL
        },
        Case {
            name: "receiver.json: step length 1e-30 m",
            receiver: Some(r#"{"pdr":{"step_length_m":1e-30}}"#),
            stderr: &["pdr.step_length_m = 1e-30 is outside [0.2, 1.5] m"],
            ..FAIL
        },
        Case {
            name: "receiver.json: receiver height 1e6 m",
            receiver: Some(r#"{"receiver_height_m":1e6}"#),
            stderr: &["receiver_height_m = 1e6 is outside [0, 3] m"],
            ..FAIL
        },
        Case {
            name: "receiver.json: the array [1, 2]",
            receiver: Some("[1, 2]"),
            stderr: &["receiver.json must be a JSON object, found an array"],
            ..FAIL
        },
        Case {
            name: "receiver.json: m_min > m_max",
            receiver: Some(r#"{"m_min":0.02,"m_nom":0.02,"m_max":0.01}"#),
            stderr: &["need m_min <= m_nom <= m_max"],
            ..FAIL
        },
        Case {
            name: "receiver.json: moment 5 A·m²",
            receiver: Some(r#"{"m_max":5}"#),
            stderr: &["m_max = 5 is outside [0.0001, 1] A·m²"],
            ..FAIL
        },
        Case {
            name: "receiver.json: imu.hz 1e308",
            receiver: Some(r#"{"imu":{"hz":1e308}}"#),
            stderr: &["imu.hz = 1e308 is outside [1, 10000] Hz"],
            ..FAIL
        },
        Case {
            name: "receiver.json: negative gyro noise",
            receiver: Some(r#"{"imu":{"gyr_noise_rad_s":-0.1}}"#),
            stderr: &["imu.gyr_noise_rad_s = -0.1 is outside [0, 1] rad/s"],
            ..FAIL
        },
        Case {
            name: "receiver.json: k_sen 2",
            receiver: Some(r#"{"pulse_noise":{"k_sen":2}}"#),
            stderr: &["pulse_noise.k_sen = 2 is outside [0, 0.5]"],
            ..FAIL
        },
        Case {
            name: "receiver.json: sigma_bkg 1 A/m",
            receiver: Some(r#"{"pulse_noise":{"sigma_bkg_A_per_m":1}}"#),
            stderr: &["pulse_noise.sigma_bkg_A_per_m = 1 is outside"],
            ..FAIL
        },
        Case {
            // Found by the `receiver_json` fuzz target: 0 passed this check and was then
            // refused by the firmware's filter (σ_bkg must be > 0).
            name: "receiver.json: sigma_bkg 0 A/m",
            receiver: Some(r#"{"pulse_noise":{"sigma_bkg_A_per_m":0}}"#),
            stderr: &["pulse_noise.sigma_bkg_A_per_m = 0 is outside [0.000000000001, 0.00001]"],
            ..FAIL
        },
        Case {
            name: "receiver.json: depth range reversed",
            receiver: Some(r#"{"victim_depth_range_m":[3,1]}"#),
            stderr: &["victim_depth_range_m = [3, 1]: the first must not exceed the second"],
            ..FAIL
        },
        Case {
            name: "receiver.json: depth range of one number",
            receiver: Some(r#"{"victim_depth_range_m":[1]}"#),
            stderr: &["victim_depth_range_m must be two numbers [min, max]"],
            ..FAIL
        },
        Case {
            name: "receiver.json: sign_ambiguous \"yes\"",
            receiver: Some(r#"{"sign_ambiguous":"yes"}"#),
            stderr: &["sign_ambiguous must be true or false, found a string"],
            ..FAIL
        },
        Case {
            name: "receiver.json: NaN",
            receiver: Some(r#"{"m_min":NaN}"#),
            stderr: &["expected value"],
            ..FAIL
        },
        Case {
            name: "receiver.json: not JSON",
            receiver: Some("m_min = 0.003"),
            stderr: &["parsing", "receiver.json"],
            ..FAIL
        },
        Case {
            name: "receiver.json: empty",
            receiver: Some(""),
            stderr: &["EOF while parsing"],
            ..FAIL
        },
        Case {
            name: "receiver.json with a byte-order mark",
            receiver: Some("\u{feff}{}"),
            truth: None,
            ..OK
        },
        Case {
            name: "receiver.json: unknown keys are ignored",
            receiver: Some(r#"{"future":{"x":[1]},"imu":{"y":"z"}}"#),
            truth: None,
            ..OK
        },
        // --- many warnings, inspect ----------------------------------------------------------
        Case {
            name: "5000 garbage lines: warnings capped",
            log: |l| {
                let i = middle(l, "imu");
                let mut v = owned(l);
                for k in 0..5000 {
                    v.insert(i, format!("#{k} ~~~"));
                }
                joined(&v)
            },
            stderr: &[
                "4980 more warning(s) not shown (5000 in all)",
                "5000 malformed",
            ],
            ..OK
        },
        Case {
            name: "inspect: 5000 garbage lines",
            cmd: "inspect",
            log: |l| {
                let mut v = owned(l);
                v.extend((0..5000).map(|k| format!("{k}{{")));
                joined(&v)
            },
            stderr: &["4980 more warning(s) not shown"],
            stdout: &["skipped: 5000 malformed"],
            ..OK
        },
        Case {
            name: "inspect: two captures concatenated",
            cmd: "inspect",
            log: |l| [joined(l), joined(l)].concat(),
            stdout: &[
                "segment 1 (header at line 1)",
                "segment 2 (header at line",
                "in 2 segment(s)",
            ],
            stderr: &[],
            ..OK
        },
        Case {
            name: "inspect: board order has no IMU gap",
            cmd: "inspect",
            log: |l| joined(&pulses_late(l, 0.25)),
            stdout: &["imu gaps (> 1.5 periods): 0", "skipped: 0 malformed"],
            stderr: &[],
            ..OK
        },
        Case {
            name: "inspect: empty file",
            cmd: "inspect",
            log: |_| Vec::new(),
            stderr: &["no header"],
            ..FAIL
        },
        // --- paths -----------------------------------------------------------------------------
        Case {
            name: "log path that does not exist",
            input: Input::Missing,
            stderr: &["reading"],
            ..FAIL
        },
        Case {
            name: "log path is a directory",
            input: Input::Dir,
            stderr: &["replaying"],
            ..FAIL
        },
    ]
}
