//! The joint map: tracks of all logs associated by signature, a pose graph of every
//! rescuer's dead-reckoned poses (edges with their covariances), the victims' beacons as
//! shared landmarks (edges = each track's best estimator output with its covariance) and
//! each rescuer's GNSS start fix as a prior, solved by [`super::graph::solve`] (eq. 5).
use super::graph::{self, Edge};
use super::local::LocalRun;
use super::scenario::StartFix;
use super::signature;
use serde::{Deserialize, Serialize};

/// Knobs of the joint map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapOptions {
    /// Time between pose nodes along a walk, s (plus a node at every observation).
    pub node_spacing_s: f64,
    /// A track's estimate is an observation only if its largest horizontal σ is below
    /// this, m (a mixture still spread over several modes is no landmark).
    pub max_sigma_m: f64,
    /// Clock error allowed per receiver when matching periods, ppm.
    pub clock_ppm: f64,
    /// Half-width of the strip a receiver searches either side of the walk, m.
    pub strip_half_width_m: f64,
}

impl Default for MapOptions {
    fn default() -> Self {
        Self {
            node_spacing_s: 5.0,
            max_sigma_m: 3.0,
            clock_ppm: 50.0,
            strip_half_width_m: 20.0,
        }
    }
}

/// Which rescuer's track (local `src` label) saw a victim.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sighting {
    /// Rescuer (log) index.
    pub rescuer: usize,
    /// The log's `src` label.
    pub src: u32,
    /// Whether the track localized the victim (an edge of the graph).
    pub localized: bool,
    /// That rescuer's own-map position of the victim (start fix + dead reckoning +
    /// estimate), when localized.
    pub own_p: Option<[f64; 2]>,
    /// Estimated moment magnitude of the track, A·m².
    pub moment: Option<f64>,
}

/// A victim of the joint map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapVictim {
    /// Global id (from the association).
    pub id: usize,
    /// Position (north, west), m; `None` when no track localized it.
    pub p: Option<[f64; 2]>,
    /// Covariance of `p` `[xx, xy, yy]`, m².
    pub cov: Option<[f64; 3]>,
    /// Mean estimated burial height relative to the receivers (negative: below), m.
    pub z_m: Option<f64>,
    /// Period of the signature, s.
    pub period_s: Option<f64>,
    /// Every track associated with it.
    pub seen_by: Vec<Sighting>,
}

/// One rescuer in the joint map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapRescuer {
    /// Dead-reckoned track from the start fix `[t, north, west]`.
    pub dr_track: Vec<[f64; 3]>,
    /// Corrected track `[t, north, west]`.
    pub track: Vec<[f64; 3]>,
    /// Area within the search strip of the corrected track, m².
    pub covered_area_m2: f64,
}

/// The joint map (the JSON output of `team-map`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeamMap {
    /// Victims (localized first, then heard only).
    pub victims: Vec<MapVictim>,
    /// Rescuers, in the logs' order.
    pub rescuers: Vec<MapRescuer>,
    /// Area covered by the union of all strips, m².
    pub covered_area_m2: f64,
    /// The options used.
    pub options: MapOptions,
    /// Eq. 5 at the solution and its degrees of freedom (edges×2 − nodes×2).
    pub chi2: f64,
    /// Degrees of freedom of `chi2`.
    pub dof: i64,
}

/// A track's best estimate when it is tight enough to be an observation.
fn usable(t: &super::local::Track, max_sigma_m: f64) -> Option<&super::local::Observation> {
    t.best.as_ref().filter(|o| o.sigma_h() <= max_sigma_m)
}

/// The pose nodes of one run: indices into its `dr`.
fn node_indices(run: &LocalRun, spacing: f64, must: &[usize]) -> Vec<usize> {
    let mut out = Vec::new();
    let mut last_t = f64::NEG_INFINITY;
    for (i, s) in run.dr.iter().enumerate() {
        if s.t - last_t >= spacing || i + 1 == run.dr.len() {
            out.push(i);
            last_t = s.t;
        }
    }
    out.extend_from_slice(must);
    out.sort_unstable();
    out.dedup();
    out
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Builds and solves the joint map of `runs` (one per log) with their start fixes
/// (`None`: the first log starts at the origin, any other start is free).
pub fn build(
    runs: &[LocalRun],
    starts: &[Option<StartFix>],
    opt: &MapOptions,
) -> Result<TeamMap, graph::GraphError> {
    build_filtered(runs, starts, opt, &|_, _| true)
}

/// The graph under construction: victims are nodes `0..n_victims`, then each rescuer's
/// pose nodes from `base[r]` on (`nodes[r]`: their indices into the run's `dr`).
struct Builder<'a> {
    opt: &'a MapOptions,
    edges: Vec<Edge>,
    x0: Vec<[f64; 2]>,
    nodes: Vec<Vec<usize>>,
    base: Vec<usize>,
}

impl Builder<'_> {
    /// Pose nodes of one rescuer, its start-fix prior and its dead-reckoning edges.
    fn add_poses(&mut self, run: &LocalRun, f: StartFix) {
        let must: Vec<usize> = run
            .tracks
            .iter()
            .filter_map(|t| usable(t, self.opt.max_sigma_m).map(|o| o.dr_index))
            .collect();
        let idx = node_indices(run, self.opt.node_spacing_s, &must);
        let b = self.x0.len();
        for &i in &idx {
            let p = run.dr.get(i).map_or([0.0; 2], |s| s.p);
            self.x0.push([f.p[0] + p[0], f.p[1] + p[1]]);
        }
        // The start fix as a prior on the first node (the walk's start, DR offset 0).
        if let Some(&x) = self.x0.get(b) {
            let s2 = f.sigma_m * f.sigma_m;
            self.edges.push(Edge {
                from: None,
                to: b,
                z: x,
                cov: [s2, 0.0, s2],
            });
        }
        // Dead-reckoning edges: increments of the accumulated track and covariance (the
        // per-interval errors are independent, so increments' covariances subtract).
        for (k, w) in idx.windows(2).enumerate() {
            let (Some(a), Some(c)) = (run.dr.get(w[0]), run.dr.get(w[1])) else {
                continue;
            };
            let d = sub(c.cov, a.cov);
            self.edges.push(Edge {
                from: Some(b + k),
                to: b + k + 1,
                z: [c.p[0] - a.p[0], c.p[1] - a.p[1]],
                cov: [d[0] + 1e-4, d[1], d[2] + 1e-4],
            });
        }
        self.base.push(b);
        self.nodes.push(idx);
    }

    /// Beacon edges of rescuer `r`: victim − pose = the estimator's relative position,
    /// with its covariance (IROS 2006 eq. 18); the first one also seeds the victim's
    /// initial guess.
    fn add_beacons(
        &mut self,
        r: usize,
        run: &LocalRun,
        ids: &[usize],
        keep: &dyn Fn(usize, usize) -> bool,
    ) {
        let (Some(&b), Some(idx)) = (self.base.get(r), self.nodes.get(r)) else {
            return;
        };
        for (t, &id) in run.tracks.iter().zip(ids) {
            let Some(o) = usable(t, self.opt.max_sigma_m).filter(|_| keep(r, id)) else {
                continue;
            };
            let Ok(k) = idx.binary_search(&o.dr_index) else {
                continue;
            };
            self.edges.push(Edge {
                from: Some(b + k),
                to: id,
                z: [o.p[0], o.p[1]],
                cov: [o.cov[0], o.cov[1], o.cov[4]],
            });
            let pose = self.x0.get(b + k).copied();
            if let (Some(v), Some(p)) = (self.x0.get_mut(id), pose)
                && v[0].is_nan()
            {
                *v = [p[0] + o.p[0], p[1] + o.p[1]];
            }
        }
    }

    /// Victims nobody localized are not in the graph: a pinned dummy prior keeps the
    /// normal matrix regular (they are reported without a position). Returns which of the
    /// first `n` nodes are localized victims.
    fn pin_unlocalized(&mut self, n: usize) -> Vec<bool> {
        let localized: Vec<bool> = self.x0.iter().take(n).map(|v| !v[0].is_nan()).collect();
        for (id, ok) in localized.iter().enumerate() {
            if !ok {
                self.edges.push(Edge {
                    from: None,
                    to: id,
                    z: [0.0; 2],
                    cov: [1.0, 0.0, 1.0],
                });
                if let Some(v) = self.x0.get_mut(id) {
                    *v = [0.0; 2];
                }
            }
        }
        localized
    }
}

/// Every track of every run that the association gave global id `id`, with the own-map
/// positions; also the mean estimated height and the period.
fn sightings(
    runs: &[LocalRun],
    ids: &[Vec<usize>],
    fix: &dyn Fn(usize) -> StartFix,
    opt: &MapOptions,
    id: usize,
) -> (Vec<Sighting>, Option<f64>, Option<f64>) {
    let mut seen_by = Vec::new();
    let (mut z, mut nz, mut period) = (0.0, 0u32, None);
    for (r, run) in runs.iter().enumerate() {
        let f = fix(r);
        let labels = ids.get(r).map_or(&[][..], |v| v);
        for (t, _) in run.tracks.iter().zip(labels).filter(|(_, g)| **g == id) {
            period = period.or(t.signature.as_ref().map(|s| s.period_s));
            let own_p = usable(t, opt.max_sigma_m).and_then(|o| {
                let d = run.dr.get(o.dr_index)?;
                z += o.p[2];
                nz += 1;
                Some([f.p[0] + d.p[0] + o.p[0], f.p[1] + d.p[1] + o.p[1]])
            });
            seen_by.push(Sighting {
                rescuer: r,
                src: t.src,
                localized: own_p.is_some(),
                own_p,
                moment: t.best.as_ref().map(|o| o.moment),
            });
        }
    }
    (seen_by, (nz > 0).then(|| z / f64::from(nz)), period)
}

/// [`build`] with only the beacon edges for which `keep(rescuer, victim id)` holds (to
/// study a beacon seen by fewer rescuers).
pub fn build_filtered(
    runs: &[LocalRun],
    starts: &[Option<StartFix>],
    opt: &MapOptions,
    keep: &dyn Fn(usize, usize) -> bool,
) -> Result<TeamMap, graph::GraphError> {
    let sigs: Vec<Vec<_>> = runs
        .iter()
        .map(|r| r.tracks.iter().map(|t| t.signature.clone()).collect())
        .collect();
    let ids = signature::associate(&sigs, opt.clock_ppm);
    let n_victims = ids.iter().flatten().map(|&i| i + 1).max().unwrap_or(0);
    // Without a fix, the first log defines the frame and the others float (σ 1 km).
    let fix = |r: usize| -> StartFix {
        starts.get(r).copied().flatten().unwrap_or(StartFix {
            p: [0.0; 2],
            sigma_m: if r == 0 { 0.01 } else { 1e3 },
        })
    };
    let mut g = Builder {
        opt,
        edges: Vec::new(),
        x0: vec![[f64::NAN; 2]; n_victims],
        nodes: Vec::new(),
        base: Vec::new(),
    };
    for (r, run) in runs.iter().enumerate() {
        g.add_poses(run, fix(r));
        g.add_beacons(r, run, ids.get(r).map_or(&[][..], |v| v), keep);
    }
    let localized = g.pin_unlocalized(n_victims);
    let sol = graph::solve(g.x0.len(), &g.edges, &g.x0)?;
    let pinned = localized.iter().filter(|&&l| !l).count();
    let dof = 2 * (g.edges.len() - pinned) as i64 - 2 * (g.x0.len() - pinned) as i64;
    let mut victims: Vec<MapVictim> = (0..n_victims)
        .map(|id| {
            let (seen_by, z_m, period_s) = sightings(runs, &ids, &fix, opt, id);
            let ok = localized.get(id).copied().unwrap_or(false);
            MapVictim {
                id,
                p: ok.then(|| sol.x.get(id).copied()).flatten(),
                cov: ok.then(|| sol.cov.get(id).copied()).flatten(),
                z_m,
                period_s,
                seen_by,
            }
        })
        .collect();
    victims.sort_by_key(|v| v.p.is_none());
    let rescuers: Vec<MapRescuer> = runs
        .iter()
        .zip(g.nodes.iter().zip(&g.base))
        .enumerate()
        .map(|(r, (run, (idx, &b)))| corrected(run, idx, b, &sol.x, &g.x0, fix(r)))
        .collect();
    let mut map = TeamMap {
        victims,
        rescuers,
        covered_area_m2: 0.0,
        options: *opt,
        chi2: sol.chi2,
        dof,
    };
    cover(&mut map);
    Ok(map)
}

/// The dead-reckoned and corrected tracks of one rescuer: the correction of each sample
/// is interpolated in time between the corrections of its two neighbouring nodes.
fn corrected(
    run: &LocalRun,
    idx: &[usize],
    base: usize,
    x: &[[f64; 2]],
    x0: &[[f64; 2]],
    f: StartFix,
) -> MapRescuer {
    let delta = |k: usize| {
        let (a, b) = (
            x.get(base + k).copied().unwrap_or([0.0; 2]),
            x0.get(base + k).copied().unwrap_or([0.0; 2]),
        );
        [a[0] - b[0], a[1] - b[1]]
    };
    let mut dr_track = Vec::new();
    let mut track = Vec::new();
    let mut k = 0;
    let mut last_t = f64::NEG_INFINITY;
    for (i, s) in run.dr.iter().enumerate() {
        while k + 1 < idx.len() && idx[k + 1] <= i {
            k += 1;
        }
        if s.t - last_t < 1.0 && i + 1 != run.dr.len() {
            continue;
        }
        last_t = s.t;
        let (ta, tb) = (
            run.dr.get(idx[k]).map_or(s.t, |d| d.t),
            idx.get(k + 1)
                .and_then(|&j| run.dr.get(j))
                .map_or(s.t, |d| d.t),
        );
        let w = if tb > ta {
            ((s.t - ta) / (tb - ta)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (da, db) = (delta(k), delta((k + 1).min(idx.len() - 1)));
        let p = [f.p[0] + s.p[0], f.p[1] + s.p[1]];
        dr_track.push([s.t, p[0], p[1]]);
        track.push([
            s.t,
            p[0] + da[0] + w * (db[0] - da[0]),
            p[1] + da[1] + w * (db[1] - da[1]),
        ]);
    }
    MapRescuer {
        dr_track,
        track,
        covered_area_m2: 0.0,
    }
}

/// Distance from `p` to the segment `a`–`b`.
fn seg_dist(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    let u = if l2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - u * dx).hypot(p[1] - a[1] - u * dy)
}

/// Centres of the 1 m cells within the strip half-width of each rescuer's corrected
/// track: `(cell, bit r set when rescuer r covers it)`.
pub fn covered_cells(map: &TeamMap) -> Vec<([f64; 2], u32)> {
    let w = map.options.strip_half_width_m;
    let polys: Vec<Vec<[f64; 2]>> = map
        .rescuers
        .iter()
        .map(|r| r.track.iter().step_by(3).map(|p| [p[1], p[2]]).collect())
        .collect();
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in polys.iter().flatten() {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    let mut out = Vec::new();
    if lo[0] > hi[0] || !w.is_finite() || w < 0.0 {
        return out;
    }
    let (nx, ny) = (
        ((hi[0] - lo[0]) + 2.0 * w) as usize + 1,
        ((hi[1] - lo[1]) + 2.0 * w) as usize + 1,
    );
    for ix in 0..nx {
        for iy in 0..ny {
            let c = [lo[0] - w + ix as f64 + 0.5, lo[1] - w + iy as f64 + 0.5];
            let mut bits = 0u32;
            for (r, poly) in polys.iter().enumerate() {
                let near = match poly.as_slice() {
                    [] => false,
                    [p] => seg_dist(c, *p, *p) <= w,
                    _ => poly.windows(2).any(|s| seg_dist(c, s[0], s[1]) <= w),
                };
                if near {
                    bits |= 1 << r.min(31);
                }
            }
            if bits != 0 {
                out.push((c, bits));
            }
        }
    }
    out
}

/// Fills the covered areas (1 m² per covered cell of [`covered_cells`]).
fn cover(map: &mut TeamMap) {
    let cells = covered_cells(map);
    for (r, res) in map.rescuers.iter_mut().enumerate() {
        res.covered_area_m2 = cells.iter().filter(|c| c.1 & (1 << r.min(31)) != 0).count() as f64;
    }
    map.covered_area_m2 = cells.len() as f64;
}
