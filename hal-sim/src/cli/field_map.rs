//! `hal-sim field-map`: the field magnitude of one beacon on a horizontal grid.
use anyhow::{Result, bail};
use firmware::{Vec3, dipole};
use std::io::Write;

/// Options of `hal-sim field-map`.
#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Half-width of the square map around the beacon, m.
    #[arg(long, default_value_t = 40.0)]
    pub half_width_m: f32,
    /// Grid cells per side.
    #[arg(long, default_value_t = 41)]
    pub cells: usize,
    /// Burial depth of the beacon below the receiver's plane, m.
    #[arg(long, default_value_t = 1.5)]
    pub depth_m: f32,
    /// Magnetic moment of the beacon (north, west, up), A·m².
    #[arg(long, num_args = 3, value_delimiter = ',', default_values_t = [0.02, 0.0, 0.0])]
    pub moment: Vec<f32>,
}

/// Characters from the weakest to the strongest field decade.
const SHADES: &[u8] = b" .:-=+*#%@";

/// Writes the map: one row per grid line (north up, west left), one shade per decade of
/// |H| from 1e-9 A/m, then a legend.
pub fn run(args: &Args, out: &mut impl Write) -> Result<()> {
    if args.cells < 2 || args.cells > 400 || args.half_width_m.is_nan() || args.half_width_m <= 0.0
    {
        bail!("--cells must be in 2..=400 and --half-width-m positive");
    }
    let m = Vec3::new(args.moment[0], args.moment[1], args.moment[2]);
    let step = 2.0 * args.half_width_m / (args.cells - 1) as f32;
    for row in 0..args.cells {
        let north = args.half_width_m - row as f32 * step;
        let mut line = String::with_capacity(args.cells);
        for col in 0..args.cells {
            let west = args.half_width_m - col as f32 * step;
            let r = Vec3::new(north, west, args.depth_m);
            line.push(match dipole::field(&r, &m) {
                Ok(h) => shade(h.norm()),
                Err(_) => 'X',
            });
        }
        writeln!(out, "{line}")?;
    }
    writeln!(
        out,
        "|H| per cell, one shade per decade from 1e-9 A/m: '{}'; X = at the beacon",
        String::from_utf8_lossy(SHADES)
    )?;
    Ok(())
}

fn shade(h: f32) -> char {
    let decade = (h.log10() + 9.0)
        .floor()
        .clamp(0.0, (SHADES.len() - 1) as f32);
    SHADES[decade as usize] as char
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_is_strongest_over_the_beacon() {
        let args = Args {
            half_width_m: 10.0,
            cells: 21,
            depth_m: 1.0,
            moment: vec![0.02, 0.0, 0.0],
        };
        let mut out = Vec::new();
        run(&args, &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        let rows: Vec<&str> = text.lines().take(21).collect();
        let centre = rows[10].as_bytes()[10];
        let corner = rows[0].as_bytes()[0];
        let rank = |c: u8| SHADES.iter().position(|&s| s == c).unwrap();
        assert!(rank(centre) > rank(corner));
    }
}
