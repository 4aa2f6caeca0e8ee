#!/usr/bin/env python3
"""Scores `hal-sim replay` output against a truth file (both JSON Lines, spec format).

Usage: score_replay.py TRUTH REPLAY
Prints one JSON object: the final 3-D and horizontal error of the first victim estimate
(robocentric, G_k axes = W axes, origin at the receiver at the pulse), the true distance,
whether the truth lies inside the reported 3-sigma ellipsoid, and the pulse counts.
"""
import json
import sys


def inv3(a):
    (a0, a1, a2), (a3, a4, a5), (a6, a7, a8) = a
    det = a0 * (a4 * a8 - a5 * a7) - a1 * (a3 * a8 - a5 * a6) + a2 * (a3 * a7 - a4 * a6)
    return [[(a4 * a8 - a5 * a7) / det, (a2 * a7 - a1 * a8) / det, (a1 * a5 - a2 * a4) / det],
            [(a5 * a6 - a3 * a8) / det, (a0 * a8 - a2 * a6) / det, (a2 * a3 - a0 * a5) / det],
            [(a3 * a7 - a4 * a6) / det, (a1 * a6 - a0 * a7) / det, (a0 * a4 - a1 * a3) / det]]


def relative_truth(truth, t):
    """True victim position relative to the receiver at `t` (linear between records)."""
    later = next((k for k, r in enumerate(truth) if r["t"] >= t), len(truth) - 1)
    a, b = truth[max(later - 1, 0)], truth[later]
    u = 0.0 if b["t"] <= a["t"] else min(1.0, max(0.0, (t - a["t"]) / (b["t"] - a["t"])))
    rx = [a["p"][i] + u * (b["p"][i] - a["p"][i]) for i in range(3)]
    return [b["victims"][0]["p"][i] - rx[i] for i in range(3)]


def main():
    truth = [r for r in map(json.loads, open(sys.argv[1])) if r.get("type") == "truth"]
    lines = [json.loads(l) for l in open(sys.argv[2]) if l.strip()]
    with_est = [l for l in lines if l["victims"]]
    if not with_est:
        print(json.dumps({"pulses": len(lines), "estimates": 0}))
        return
    last = with_est[-1]
    rel = relative_truth(truth, last["t"])
    est = last["victims"][0]
    e = [est["p"][i] - rel[i] for i in range(3)]
    cov = [est["cov"][0:3], est["cov"][3:6], est["cov"][6:9]]
    ci = inv3(cov)
    nees = sum(e[i] * ci[i][j] * e[j] for i in range(3) for j in range(3))
    print(json.dumps({
        "pulses": len(lines), "estimates": len(with_est), "status": last.get("status"),
        "true_dist_m": round(sum(x * x for x in rel) ** 0.5, 3),
        "err3d_m": round(sum(x * x for x in e) ** 0.5, 3),
        "err_h_m": round((e[0] ** 2 + e[1] ** 2) ** 0.5, 3),
        "err_z_m": round(e[2], 3), "nees": round(nees, 2), "inside_3sigma": nees <= 14.16,
    }))


if __name__ == "__main__":
    main()
