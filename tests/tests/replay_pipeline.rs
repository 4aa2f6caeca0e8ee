//! End to end on the PC: a seeded simulated search → session log → `replay` through the
//! firmware's own pipeline (attitude, PDR, SOGs filter) → the estimate at the last pulse
//! compared with the simulator's ground truth.
use hal_sim::io::replay::{ReplayLine, replay_with_config};
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};

#[test]
fn replay_of_simulated_searches_finds_the_victim() {
    let mut worst = 0.0f64;
    for seed in [3, 7, 11] {
        let sim = simulate(&ScenarioConfig::new(Preset::Paper, seed));
        // Round trip through the log bytes, as an outside tool would hand them over.
        let session = hal_sim::io::session::read(sim.session_bytes().as_slice()).unwrap();
        let mut out = Vec::new();
        let lines = replay_with_config(&session, &sim.receiver, &mut out).unwrap();
        assert_eq!(lines, session.pulses().count());
        let text = String::from_utf8(out).unwrap();
        let last: ReplayLine = serde_json::from_str(text.lines().last().unwrap()).unwrap();
        let victim = last.victims.first().expect("an estimate at the last pulse");
        let receiver = sim.world.rescuer_state(last.t).p;
        let truth = sim.world.transmitters[0].position;
        let err = (0..3)
            .map(|i| (victim.p[i] - (truth[i] - receiver[i])).powi(2))
            .sum::<f64>()
            .sqrt();
        println!(
            "seed {seed}: final 3-D error {err:.3} m, {} components",
            last.n_components
        );
        worst = worst.max(err);
        assert!(victim.cov.iter().all(|c| c.is_finite()));
    }
    // Open-loop walks ending 1–5 m from the victim: a broken pipeline is metres off.
    assert!(worst < 0.6, "worst final error {worst:.3} m");
}
