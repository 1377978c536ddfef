#!/usr/bin/env python3
"""Records a plant with physics that `jetbench`'s effect catalogue does not hold, simulated
independently of jetbench (its own RK4 and its own noise), for the concealed scenario suite.

    scripts/outside_catalogue.py --plant plants/p100-diesel.toml --profile campaign.csv \\
        --physics heat_soak:loss_per_n=0.0004,time_constant_s=45 --noise-var 7 --seed 3 --out case.csv

The model is jetbench's (docs/model/README.md), T'' = f(T, T') + g(T, T')*v(u), integrated by RK4 at 1 kHz with the
throttle of each 10 ms row held, and one of:

- heat_soak: loss_per_n, time_constant_s. The engine loses input gain as it heat-soaks: the
  gain is scaled by (1 - loss_per_n*H), H following the thrust with a first-order lag.
- fuel_soak: loss_per_pct, time_constant_s. The same loss driven by the fuel schedule: H
  follows v(u) (in % of throttle map) instead of the thrust.
- dead_band: edge_pct. Below the edge the ECU's throttle map is flat: the engine runs as if
  at the edge.
- soft_dead_band: edge_pct, width_pct. The same with a rounded edge:
  u' = (u + edge + sqrt((u - edge)^2 + width^2)) / 2.

The engine starts at rest at the first throttle (the history settled there too), the noise is
white Gaussian from --seed, and time, throttle and thrust are written at the bench's resolution
(0.01 s, 0.01 %, 0.01 N) as `time_s,throttle_pct,thrust_n`. Standard library only.
"""

import argparse
import csv
import math
import random
import tomllib

KEYS = ["K_T", "K_TT", "K_D", "K_DD", "K_TD", "c", "B_U", "B_T", "B_D", "B_UU"]
STEP_S = 0.01
SUBSTEPS = 10


def parse_spec(spec):
    """`name:key=value,...` as (name, {key: value}): the form of --effect and of --physics."""
    name, _, rest = spec.partition(":")
    values = {}
    for pair in filter(None, rest.split(",")):
        key, _, value = pair.partition("=")
        values[key.strip()] = float(value)
    return name.strip(), values


def parse_physics(spec):
    name, values = parse_spec(spec)
    needed = {
        "heat_soak": ["loss_per_n", "time_constant_s"],
        "fuel_soak": ["loss_per_pct", "time_constant_s"],
        "dead_band": ["edge_pct"],
        "soft_dead_band": ["edge_pct", "width_pct"],
    }
    if name not in needed or sorted(values) != sorted(needed[name]):
        raise SystemExit(f"unknown physics {spec!r}; expected one of {needed}")
    return name, values


class Engine:
    def __init__(self, p, physics, values):
        self.p, self.physics, self.values = p, physics, values

    def v(self, u):
        return u + self.p["B_UU"] * u * u

    def throttle_map(self, u):
        """v of the throttle the engine actually follows."""
        if self.physics == "dead_band":
            u = max(u, self.values["edge_pct"])
        elif self.physics == "soft_dead_band":
            e, w = self.values["edge_pct"], self.values["width_pct"]
            u = 0.5 * (u + e + math.sqrt((u - e) ** 2 + w * w))
        return self.v(u)

    def accel(self, t, d, vu, h):
        p = self.p
        f = p["K_T"] * t + p["K_TT"] * t * t + p["K_D"] * d + p["K_DD"] * d * d + p["K_TD"] * t * d + p["c"]
        g = p["B_U"] + p["B_T"] * t + p["B_D"] * d
        if self.physics == "heat_soak":
            g *= 1.0 - self.values["loss_per_n"] * h
        elif self.physics == "fuel_soak":
            g *= 1.0 - self.values["loss_per_pct"] * h
        return f + g * vu

    def history_input(self, t, vu):
        return t if self.physics == "heat_soak" else vu

    def step(self, state, u):
        """One 10 ms row: RK4 substeps with the throttle held, the history a first-order lag."""
        t, d, h = state
        vu = self.throttle_map(u)
        dt = STEP_S / SUBSTEPS
        tau = self.values.get("time_constant_s")
        for _ in range(SUBSTEPS):
            k1 = (d, self.accel(t, d, vu, h))
            k2 = (d + 0.5 * dt * k1[1], self.accel(t + 0.5 * dt * k1[0], d + 0.5 * dt * k1[1], vu, h))
            k3 = (d + 0.5 * dt * k2[1], self.accel(t + 0.5 * dt * k2[0], d + 0.5 * dt * k2[1], vu, h))
            k4 = (d + dt * k3[1], self.accel(t + dt * k3[0], d + dt * k3[1], vu, h))
            t, d = (t + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                    d + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))
            if tau:
                h += (self.history_input(t, vu) - h) * (1.0 - math.exp(-dt / tau))
            if not (math.isfinite(t) and abs(t) < 1e4):
                raise SystemExit("the plant diverged")
        return t, d, h


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plant", required=True, help="model file with [model] (the ten parameters)")
    parser.add_argument("--profile", required=True, help="CSV time_s,throttle_pct (jetbench excite)")
    parser.add_argument("--physics", required=True)
    parser.add_argument("--noise-var", type=float, default=7.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()

    with open(args.plant, "rb") as f:
        p = tomllib.load(f)["model"]
    physics, values = parse_physics(args.physics)
    engine = Engine({k: float(p[k]) for k in KEYS}, physics, values)
    with open(args.profile) as f:
        rows = [(round(float(r["time_s"]), 2), round(float(r["throttle_pct"]), 2)) for r in csv.DictReader(f)]
    # At rest at the first throttle: settle (two minutes, or eight history time constants).
    state = (0.0, 0.0, 0.0)
    for _ in range(int(max(120.0, 8.0 * values.get("time_constant_s", 0.0)) / STEP_S)):
        state = engine.step(state, rows[0][1])
    rng = random.Random(args.seed)
    sigma = math.sqrt(args.noise_var)
    with open(args.out, "w") as f:
        f.write("time_s,throttle_pct,thrust_n\n")
        for k, (t_s, u) in enumerate(rows):
            y = round(state[0] + rng.gauss(0.0, sigma), 2)
            f.write(f"{t_s!r},{u!r},{y!r}\n")
            if k + 1 < len(rows):
                state = engine.step(state, u)


if __name__ == "__main__":
    main()
