//! The board's session-log writer (`firmware::session_log`) produces logs that `hal-sim`
//! (and any tool following the spec) reads back with the same values.
use firmware::{Vec3, session_log};
use hal_sim::io::session::{self, Record};
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};

fn v(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

#[test]
fn firmware_writer_round_trips_through_the_reader() {
    let sim = simulate(&ScenarioConfig::new(Preset::Paper, 5));
    let mut text = String::new();
    let h = &sim.session.header;
    let earth = h.earth_field_ut.unwrap();
    session_log::write_header(&mut text, h.imu_hz as f32, &v(&earth), h.sign_ambiguous).unwrap();
    for r in &sim.session.records {
        match r {
            Record::Imu(s) => {
                let mag = s.mag.as_ref().map(v);
                session_log::write_imu(&mut text, s.t, &v(&s.acc), &v(&s.gyr), mag.as_ref())
                    .unwrap()
            }
            Record::Pulse(p) => {
                session_log::write_pulse(&mut text, p.t, &v(&p.h), p.src.map(|s| s as u8)).unwrap()
            }
            Record::Truth(_) => {}
        }
    }
    let back = session::read(text.as_bytes()).unwrap();
    assert!(back.warnings.is_empty());
    assert_eq!(back.records.len(), sim.session.records.len());
    let close = |a: &[f64; 3], b: &[f64; 3]| {
        (0..3).all(|i| (a[i] - b[i]).abs() <= 1e-6 * b[i].abs().max(1e-30))
    };
    for (a, b) in back.records.iter().zip(&sim.session.records) {
        match (a, b) {
            (Record::Imu(x), Record::Imu(y)) => {
                assert_eq!(x.t, y.t);
                assert!(close(&x.acc, &y.acc) && close(&x.gyr, &y.gyr));
            }
            (Record::Pulse(x), Record::Pulse(y)) => {
                assert_eq!(x.t, y.t);
                assert!(close(&x.h, &y.h), "{:?} vs {:?}", x.h, y.h);
            }
            _ => panic!("record kinds differ"),
        }
    }
}
