#!/usr/bin/env python3
"""An independent generator of `arva-session` v1 logs (docs/session-log.md).

Written from the spec alone, without hal-sim's code, so that `hal-sim replay` can be
checked on logs whose walk, gait, device attitude, noise draws and timing are not the
simulator's own: the firmware must work from the physics, not from hal-sim's quirks.

What differs from hal-sim on purpose: the path is a pursuit curve (the walker starts
off-bearing and turns in with a limited turn rate, speed 0.8–1.2 m/s, step 1.6–2.1 Hz),
the device is carried pitched down 5–20° with a sway at half the step rate, pulse periods
are drawn anywhere in 0.8–1.2 s with jitter, the IMU rate can be 50–200 Hz, the log
carries unknown keys and an unknown record type (readers must ignore them), and the
moment range of the receiver file is the standard's (spec example), not hal-sim's.

Usage: independent_log.py SEED OUT_DIR [--imu-hz HZ] [--stand S] [--on-bearing] [--cut S]
       [--uncalibrated] [--pass]
Writes OUT_DIR/session.jsonl, OUT_DIR/truth.jsonl, OUT_DIR/receiver.json.
Pure Python (math, random, json): runs anywhere python3 runs.
"""
import json
import math
import os
import random
import sys

G = 9.80665
DT = 0.001  # kinematics grid, s


def rot(roll, pitch, yaw):
    """R_WR = Rz(yaw) Ry(pitch) Rx(roll), row-major 3x3."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def mat_t_vec(r, v):
    """R^T v."""
    return [sum(r[i][j] * v[i] for i in range(3)) for j in range(3)]


def dipole_h(m, r):
    """Field strength of a point dipole (A/m): (3 r^ (m.r^) - m) / (4 pi |r|^3)."""
    d = math.sqrt(sum(x * x for x in r))
    u = [x / d for x in r]
    mu = sum(a * b for a, b in zip(m, u))
    k = 1.0 / (4.0 * math.pi * d ** 3)
    return [k * (3.0 * mu * u[i] - m[i]) for i in range(3)]


def unit_random(rng):
    while True:
        v = [rng.gauss(0, 1) for _ in range(3)]
        n = math.sqrt(sum(x * x for x in v))
        if n > 1e-6:
            return [x / n for x in v]


def walk(rng, victim, start, stop_dist, stand_s=0.0, off_bearing=True):
    """The walker's kinematics on a DT grid: position of the device and its attitude."""
    speed = rng.uniform(0.8, 1.2)
    f_step = rng.uniform(1.6, 2.1)
    height = rng.uniform(0.9, 1.2)
    bounce = rng.uniform(0.015, 0.035)
    pitch0 = -math.radians(rng.uniform(5, 20))
    turn_max = rng.uniform(0.3, 0.6)  # rad/s
    to_victim = math.atan2(victim[1] - start[1], victim[0] - start[0])
    heading = to_victim + rng.choice([-1, 1]) * math.radians(rng.uniform(20, 50)) * off_bearing
    x, y, t = start[0], start[1], 0.0
    phase_sway = rng.uniform(0, 2 * math.pi)
    out = []
    while True:
        dx, dy = victim[0] - x, victim[1] - y
        if math.hypot(dx, dy) < stop_dist or t > 240.0:
            break
        want = math.atan2(dy, dx)
        err = math.atan2(math.sin(want - heading), math.cos(want - heading))
        # The gait and the speed ramp in smoothly after standing (a walker does not
        # start at full speed, and a jump in the kinematics would be a spike in the IMU).
        u = min(1.0, max(0.0, (t - stand_s) / 1.5))
        g = u * u * (3.0 - 2.0 * u)
        v = g * speed * (1.0 + 0.12 * math.sin(2 * math.pi * f_step * t))
        if g > 0.0:
            heading += max(-turn_max * DT, min(turn_max * DT, 0.8 * err * DT))
        lateral = g * 0.03 * math.sin(math.pi * f_step * t + phase_sway)
        x += v * math.cos(heading) * DT
        y += v * math.sin(heading) * DT
        px = x - lateral * math.sin(heading)
        py = y + lateral * math.cos(heading)
        pz = height + g * bounce * math.cos(2 * math.pi * f_step * t)
        roll = g * math.radians(3) * math.sin(math.pi * f_step * t + phase_sway)
        pitch = pitch0 + g * math.radians(2) * math.sin(2 * math.pi * f_step * t)
        yaw = heading + g * math.radians(4) * math.sin(math.pi * f_step * t + 1.0)
        out.append((t, [px, py, pz], [roll, pitch, yaw]))
        t += DT
    return out, speed / f_step


def euler_rates_to_body(rpy, drpy):
    """Body rate (R frame) from roll/pitch/yaw rates for R = Rz Ry Rx."""
    r, p, _ = rpy
    dr, dp, dy = drpy
    return [
        dr - math.sin(p) * dy,
        math.cos(r) * dp + math.sin(r) * math.cos(p) * dy,
        -math.sin(r) * dp + math.cos(r) * math.cos(p) * dy,
    ]


def main():
    seed = int(sys.argv[1])
    out_dir = sys.argv[2]
    imu_hz = float(sys.argv[sys.argv.index("--imu-hz") + 1]) if "--imu-hz" in sys.argv else 100.0
    rng = random.Random(seed)
    os.makedirs(out_dir, exist_ok=True)
    m_min, m_max = 0.025, 0.075
    earth = [21.0, 0.0, -42.0]
    depth = rng.uniform(0.3, 2.5)
    victim = [0.0, 0.0, -depth]
    moment = [x * rng.uniform(m_min, m_max) for x in unit_random(rng)]
    bearing = rng.uniform(-math.pi, math.pi)
    dist0 = rng.uniform(25.0, 40.0)
    start = [dist0 * math.cos(bearing), dist0 * math.sin(bearing)]
    stand = float(sys.argv[sys.argv.index("--stand") + 1]) if "--stand" in sys.argv else 0.0
    aim, stop = victim, rng.uniform(2.0, 4.0)
    if "--pass" in sys.argv:
        # --pass: walk over the victim and on, to a point 8 m beyond it (a primary-search
        # strip): the receiver's guidance prompts are not followed by this walker.
        far = math.hypot(victim[0] - start[0], victim[1] - start[1])
        aim = [victim[i] + 8.0 * (victim[i] - start[i]) / far for i in range(2)] + [victim[2]]
        stop = 0.5
    track, step_len = walk(rng, aim, start, stop, stand, "--on-bearing" not in sys.argv)
    gyr_bias = [rng.uniform(-0.005, 0.005) for _ in range(3)]
    sigma_bkg, k_sen = 2.59e-9, 0.03

    session = open(os.path.join(out_dir, "session.jsonl"), "w")
    truth = open(os.path.join(out_dir, "truth.jsonl"), "w")
    header = {"type": "header", "format": "arva-session", "version": 1, "imu_hz": imu_hz,
              "earth_field_uT": earth, "sign_ambiguous": True, "generator": "independent_log.py"}
    session.write(json.dumps(header) + "\n")
    session.write(json.dumps({"type": "note", "t": 0.0, "text": "unknown type: skip"}) + "\n")

    n = len(track)
    imu_every = max(1, int(round(1.0 / imu_hz / DT)))
    period = rng.uniform(0.8, 1.2)
    next_pulse = rng.uniform(0.2, 1.0)
    k = 2
    records = []
    while k < n - 2:
        t, p, rpy = track[k]
        if k % imu_every == 0:
            acc_w = [(track[k + 1][1][i] - 2 * p[i] + track[k - 1][1][i]) / DT ** 2 for i in range(3)]
            r_wr = rot(*rpy)
            f_w = [acc_w[0], acc_w[1], acc_w[2] + G]
            acc = [v + rng.gauss(0, 0.05) for v in mat_t_vec(r_wr, f_w)]
            drpy = [(track[k + 1][2][i] - track[k - 1][2][i]) / (2 * DT) for i in range(3)]
            gyr = [w + b + rng.gauss(0, 0.005) for w, b in zip(euler_rates_to_body(rpy, drpy), gyr_bias)]
            mag = [v + rng.gauss(0, 0.3) for v in mat_t_vec(r_wr, earth)]
            records.append({"type": "imu", "t": round(t, 6), "acc": acc, "gyr": gyr, "mag": mag,
                            "temp_C": -5.0})
        if t >= next_pulse:
            r_wr = rot(*rpy)
            rel = [p[i] - victim[i] for i in range(3)]
            h_w = dipole_h(moment, rel)
            h_r = mat_t_vec(r_wr, h_w)
            mag_h = math.sqrt(sum(x * x for x in h_r))
            sd = math.sqrt(sigma_bkg ** 2 + (k_sen * mag_h) ** 2)
            sign = rng.choice([-1.0, 1.0])
            h = [sign * (x + rng.gauss(0, sd)) for x in h_r]
            if mag_h > 3 * sigma_bkg:
                records.append({"type": "pulse", "t": round(t, 6), "h": h})
            truth.write(json.dumps({"type": "truth", "t": round(t, 6), "p": p, "rpy": rpy,
                                    "victims": [{"p": victim, "m": moment}]}) + "\n")
            next_pulse = t + period + rng.uniform(-0.02, 0.02)
        k += 1
    # --cut S: the receiver was switched to search mode S seconds into the walk.
    cut = float(sys.argv[sys.argv.index("--cut") + 1]) if "--cut" in sys.argv else 0.0
    for rec in records:
        if rec["t"] >= cut:
            session.write(json.dumps(rec) + "\n")
    session.close()
    truth.close()
    calibrated = step_len * (1.0 + rng.gauss(0, 0.02))
    receiver = {"m_min": m_min, "m_max": m_max, "m_nom": 0.05, "sign_ambiguous": True,
                "pulse_noise": {"sigma_bkg_A_per_m": sigma_bkg, "k_sen": k_sen},
                "imu": {"hz": imu_hz, "gyr_noise_rad_s": 0.005, "gyr_bias_max_rad_s": 0.01,
                        "acc_noise_m_s2": 0.05, "mag_noise_uT": 0.3},
                "victim_depth_range_m": [0.0, 3.0], "receiver_height_m": 1.0,
                "pdr": {"step_length_m": calibrated}}
    if "--uncalibrated" in sys.argv:
        del receiver["pdr"]
    with open(os.path.join(out_dir, "receiver.json"), "w") as f:
        json.dump(receiver, f)


if __name__ == "__main__":
    main()
