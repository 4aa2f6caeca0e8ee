//! Runs the dipole model on the emulated Cortex-M4F and checks it against f64 on the host.
use e2e::{build_firmware_bin, disassemble, parse_triple, run_in_qemu, section_sizes};
use std::time::Duration;

fn field_f64(r: [f64; 3], m: [f64; 3]) -> [f64; 3] {
    let r2 = r.iter().map(|x| x * x).sum::<f64>();
    let rn = r2.sqrt();
    let mr = r[0] * m[0] + r[1] * m[1] + r[2] * m[2];
    let k = 1.0 / (4.0 * std::f64::consts::PI * rn.powi(3));
    [0, 1, 2].map(|i| k * (3.0 * mr * r[i] / r2 - m[i]))
}

fn rel_err(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt();
    d / b.iter().map(|x| x * x).sum::<f64>().sqrt()
}

#[test]
fn dipole_on_cortex_m4f_matches_host_f64() {
    let elf = build_firmware_bin("qemu_dipole", "qemu");
    // The model must run on the FPU: single-precision VFP instructions in the binary.
    let asm = disassemble(&elf);
    let vfp = asm
        .lines()
        .filter(|l| l.contains("vmul.f32") || l.contains("vadd.f32"))
        .count();
    assert!(
        vfp > 50,
        "expected VFP instructions in the firmware, found {vfp}"
    );

    let run = run_in_qemu(&elf, Duration::from_secs(120));
    assert!(
        run.success,
        "qemu_dipole failed:\n{}\n{}",
        run.stdout, run.stderr
    );
    let mut cases = 0;
    let (mut worst_h, mut worst_inv) = (0.0f64, 0.0f64);
    for line in run.stdout.lines().filter(|l| l.starts_with("case ")) {
        let field = |key: &str| {
            let start = line.find(key).expect(key) + key.len();
            line[start..].split_whitespace().next().expect("value")
        };
        let (r, m) = (parse_triple(field("r=")), parse_triple(field("m=")));
        let (h, minv) = (parse_triple(field("h=")), parse_triple(field("minv=")));
        worst_h = worst_h.max(rel_err(h, field_f64(r, m)));
        worst_inv = worst_inv.max(rel_err(minv, m));
        cases += 1;
    }
    assert!(run.stdout.contains("done 64"), "{}", run.stdout);
    assert_eq!(cases, 64);
    println!("on-target dipole: worst relative error field {worst_h:e}, inverse {worst_inv:e}");
    assert!(worst_h < 1e-5, "field worst relative error {worst_h:e}");
    assert!(
        worst_inv < 1e-5,
        "inverse worst relative error {worst_inv:e}"
    );

    let sizes = section_sizes(&elf);
    let flash: u64 = sizes
        .iter()
        .filter(|s| s.2 >= 0x0800_0000 && s.2 < 0x0810_0000)
        .map(|s| s.1)
        .sum();
    assert!(flash < 512 * 1024, "flash {flash} B");
}
