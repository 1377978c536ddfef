#!/usr/bin/env python3
"""A randomised diagnosis campaign: N cases drawn from broad distributions, simulated by this
file's own engine (written from the physics descriptions, independent of jetbench's models),
diagnosed blind with `jetbench diagnose --json`, and graded: precision of claims, recall of
effects, ambiguity rate, MAE after against the truth model's.

    scripts/diagnose-campaign.sh N SEED [--jobs 2] [--out docs/diagnose/CAMPAIGN.md]

Each case draws a plant (a preset, or one perturbed by up to 15 % per parameter), zero, one or
two effects (every catalogue effect across its documented range; outside the catalogue: heat
and fuel soak, dead bands, spool-down slower than spool-up, play in the throttle path), or a
recording artefact (a clipping force sensor, a slow periodic force on the stand), or parameters
that are off, alone or (half of those cases) beside one catalogue effect; white, coloured
(AR(1)) or heteroscedastic noise; spikes, lost rows, jittered timestamps; 100-600 s of random
steps, ramps and holds. Closed-loop cases are not drawn (they need the live stack; the fixed
scenarios hold two).

A claim is `none`, `parameters` or `missing_physics`. `parameters` is true only when the
parameters are off and nothing else is, `none` only when nothing is off (or the parameters are
off only within the ranges the claim discloses, see below). A physics claim is true
when it is right about the parameters, every effect it names is in the truth (physics outside
the catalogue: `discrepancy`), and every effect of the truth it does not name is one its verdict
disclosed as able to hide beside it, at a size no smaller than the truth's: the diagnosis's
`detectability` has a probe of that class with `would_show` false whose `could_hide` ranges hold
every value of the truth's effect (see `disclosed`). An effect the verdict did not disclose, or
disclosed at a smaller size, or whose values cannot be compared with the probe's (a time
constant other than the probe's, an effect outside the catalogue) makes the claim false. An
artefact (clipping, a periodic force) is never engine physics: every claim on such a case is
false. `ambiguous`, `unexplained` and `insufficient_data` are not claims. A claim of the part
every explanation in play holds lists what they hold beside it as undecided (`undecided` in the
diagnosis): an effect of the truth it lists there counts as disclosed. Right about the
parameters: where they are off, the claim refits them or leaves whether they are off open (a
refit among what is undecided, or `parameters_open`), or discloses ranges that hold every one of
the engine's parameters (`parameter_ranges`: how far each could be off with the recording unable
to tell, as `could_hide` does for an effect); where they are as the engine is and the
truth is all in the catalogue, it does not refit them (beside physics outside the catalogue, a
refit may take up the part of it that changes the engine's map, and is not held against the
claim). Recall counts the effects named; effects a true claim left out and disclosed are counted
apart. Beside it, the report counts recall against what each effect put into its recording
(`evidence`: the log-likelihood ratio of the noise-free reading with the effect against without
it, for an observer who knows everything else), which no diagnosis can exceed.

    python3 scripts/diagnose_campaign.py --self-test    # the grader on made-up results

`--draw 1` draws the cases as the campaigns did before parameters that are off were drawn beside
an effect (every other case is the same in both draws).
"""

import argparse
import concurrent.futures
import functools
import json
import math
import os
import random
import re
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
KEYS = ["K_T", "K_TT", "K_D", "K_DD", "K_TD", "c", "B_U", "B_T", "B_D", "B_UU"]
STEP_S = 0.01
SUBSTEPS = 5
# The engine is stepped from zero thrust at least this long before the rest of the settle is
# done in closed form (see Engine.run).
SETTLE_MIN_S = 15.0
# The engine starts from rest (zero thrust, a tared sensor, a cold engine) this long before the
# recording: slow states (a sensor drift's bias, a soak) are still on their way at its start.
SETTLE_S = 120.0
PLANTS = {
    "p100-diesel": ROOT / "recordings/scenarios/plants/p100-diesel.toml",
    "p220-kerosene": ROOT / "recordings/scenarios/plants/p220-kerosene.toml",
    "p100-fast": ROOT / "recordings/scenarios/plants/p100-fast.toml",
}
U_MIN, U_MAX = 25.0, 100.0
# How the cases are drawn (`--draw`): 2 puts an effect beside half the cases whose parameters are off.
DRAW = 2
# The longest designed experiment the campaign plays (`--discriminate`), s.
MAX_DESIGN_S = 600
CATALOGUE = ["input_delay", "actuator_lag", "rate_limit", "sensor_drift", "gain_drift", "bearing_friction",
             "stand_resonance"]
OUTSIDE = ["heat_soak", "fuel_soak", "dead_band", "soft_dead_band", "spool_asymmetry", "throttle_play"]
ARTEFACTS = ["clipping", "periodic_force"]
SENSOR_SIDE = {"sensor_drift", "bearing_friction", "stand_resonance"}


def draw_effect(rng, name):
    """Values across each effect's documented range (resonance kept below 5 Hz for the 2 ms step)."""
    u = rng.uniform
    return {
        "input_delay": lambda: {"delay_s": u(0.03, 0.3)},
        "actuator_lag": lambda: {"time_constant_s": u(0.08, 0.6)},
        "rate_limit": lambda: {"up_pct_per_s": u(20, 120), "down_pct_per_s": u(20, 150)},
        "sensor_drift": lambda: {"gain": u(0.01, 0.07), "time_constant_s": u(15, 120)},
        "gain_drift": lambda: {"per_minute": u(0.002, 0.012)},
        "bearing_friction": lambda: {"force_n": u(0.8, 3.0)},
        "stand_resonance": lambda: {"frequency_hz": u(0.8, 4.0), "damping_ratio": u(0.02, 0.15)},
        "heat_soak": lambda: {"loss_per_n": u(0.0002, 0.0006), "time_constant_s": u(20, 80)},
        "fuel_soak": lambda: {"loss_per_pct": u(0.0002, 0.0005), "time_constant_s": u(20, 80)},
        "dead_band": lambda: {"edge_pct": u(30, 40)},
        "soft_dead_band": lambda: {"edge_pct": u(29, 38), "width_pct": u(2, 5)},
        "spool_asymmetry": lambda: {"down_factor": u(0.55, 0.8)},
        "throttle_play": lambda: {"play_pct": u(0.8, 2.5)},
        "clipping": lambda: {"quantile": u(0.95, 0.99)},
        "periodic_force": lambda: {"period_s": u(15, 60), "amplitude_n": u(1.0, 3.0)},
    }[name]()


class Engine:
    """T'' = f(T, T') + g(T, T')·v(u) (docs/model/README.md), RK4 at 2 ms with the throttle path
    (delay, play, rate limit, lag) stepped at the same rate, and the sensor side after it."""

    def __init__(self, p, effects):
        self.p, self.e = p, effects
        # The inner loop's constants, looked up once (the arithmetic is the same).
        self.f = tuple(p[k] for k in ("K_T", "K_TT", "K_D", "K_DD", "K_TD", "c", "B_U", "B_T", "B_D"))
        self.heat = effects["heat_soak"]["loss_per_n"] if "heat_soak" in effects else None
        self.fuel = effects["fuel_soak"]["loss_per_pct"] if "fuel_soak" in effects else None
        self.down = effects["spool_asymmetry"]["down_factor"] if "spool_asymmetry" in effects else None

    def accel(self, t, d, vu, h, gain):
        kt, ktt, kd, kdd, ktd, c, bu, bt, bd = self.f
        f = kt * t + ktt * t * t + kd * d + kdd * d * d + ktd * t * d + c
        g = bu + bt * t + bd * d
        if self.heat is not None:
            g *= 1.0 - self.heat * h
        if self.fuel is not None:
            g *= 1.0 - self.fuel * h
        a = f + g * vu * gain
        if self.down is not None and d < 0.0:
            a *= self.down
        return a

    def v(self, u):
        e = self.e
        if "dead_band" in e:
            u = max(u, e["dead_band"]["edge_pct"])
        if "soft_dead_band" in e:
            c, w = e["soft_dead_band"]["edge_pct"], e["soft_dead_band"]["width_pct"]
            u = 0.5 * (u + c + math.sqrt((u - c) ** 2 + w * w))
        return u + self.p["B_UU"] * u * u

    def run(self, times, throttle):
        """True thrust and the force read, per row (before noise): at the row's time, before the
        row's throttle acts, as a bench samples the force and sends the command in the same tick
        (the state at the end of the row before; the first row's, at the end of the settle)."""
        e, dt = self.e, STEP_S / SUBSTEPS
        n = len(throttle)
        delay = int(round(e["input_delay"]["delay_s"] / dt)) if "input_delay" in e else 0
        # Throttle per substep (held within each row), delayed.
        u_fine = [throttle[min(n - 1, max(0, (k - delay) // SUBSTEPS))] for k in range(n * SUBSTEPS)]
        settle = int(SETTLE_S / dt)
        t, d, h = 0.0, 0.0, 0.0
        ue = up = throttle[0]
        bias, m, x, xd = 0.0, None, 0.0, 0.0
        true, read = [], []
        tau_h = (e.get("heat_soak") or e.get("fuel_soak") or {}).get("time_constant_s")
        # Each effect's constants, computed once (the same values the loop used to recompute).
        play = e["throttle_play"]["play_pct"] if "throttle_play" in e else None
        rate = (e["rate_limit"]["down_pct_per_s"] * dt, e["rate_limit"]["up_pct_per_s"] * dt) if "rate_limit" in e else None
        lag_a = 1.0 - math.exp(-dt / e["actuator_lag"]["time_constant_s"]) if "actuator_lag" in e else None
        lag = None
        per_minute = e["gain_drift"]["per_minute"] if "gain_drift" in e else None
        heat = "heat_soak" in e
        h_a = 1.0 - math.exp(-dt / tau_h) if tau_h else None
        if "stand_resonance" in e:
            w0 = 2 * math.pi * e["stand_resonance"]["frequency_hz"]
            z = e["stand_resonance"]["damping_ratio"]
        resonance = "stand_resonance" in e
        band = e["bearing_friction"]["force_n"] if "bearing_friction" in e else None
        drift = (e["sensor_drift"]["gain"], 1.0 - math.exp(-dt / e["sensor_drift"]["time_constant_s"])) \
            if "sensor_drift" in e else None
        accel, v = self.accel, self.v
        # Fast-forward the settle: once the engine is at rest (after at least SETTLE_MIN_S), the
        # rest of the two minutes moves only the slow first-order states (a sensor drift's bias,
        # a soak's history) towards their rest values, which is done in closed form, exactly as
        # the step-by-step loop would with the thrust held; a ringing stand is put at rest.
        check = -settle + int(SETTLE_MIN_S / dt)
        k = -settle
        start = -SUBSTEPS  # the settle's last row, whose end is the first row's sample
        while k < n * SUBSTEPS:
            if k == check and k < start:
                if abs(d) < 1e-7 and abs(accel(t, d, v(lag if lag is not None else ue), h, 1.0)) < 1e-7:
                    left = (start - k) * dt
                    if drift is not None:
                        bias = drift[0] * t + (bias - drift[0] * t) * math.exp(-left / e["sensor_drift"]["time_constant_s"])
                    if h_a is not None:
                        hin = t if heat else v(lag if lag is not None else ue)
                        h = hin + (h - hin) * math.exp(-left / tau_h)
                    if resonance:
                        x, xd = t, 0.0
                    if band is not None and m is not None:
                        m = min(max(m, t - band), t + band)
                    k = start
                else:
                    check += int(1.0 / dt)
            uc = u_fine[max(k, 0)]
            if play is not None:
                up = min(max(up, uc - play), uc + play)
                uc = up
            if rate is not None:
                ue += max(-rate[0], min(rate[1], uc - ue))
            else:
                ue = uc
            ua = ue
            if lag_a is not None:
                lag = ue if lag is None else lag
                lag += (ue - lag) * lag_a
                ua = lag
            vu = v(ua)
            tm = max(k, 0) * dt
            gain = 1.0 - per_minute * tm / 60.0 if per_minute is not None else 1.0
            k1 = (d, accel(t, d, vu, h, gain))
            k2 = (d + 0.5 * dt * k1[1], accel(t + 0.5 * dt * k1[0], d + 0.5 * dt * k1[1], vu, h, gain))
            k3 = (d + 0.5 * dt * k2[1], accel(t + 0.5 * dt * k2[0], d + 0.5 * dt * k2[1], vu, h, gain))
            k4 = (d + dt * k3[1], accel(t + dt * k3[0], d + dt * k3[1], vu, h, gain))
            t, d = (t + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                    d + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))
            if h_a is not None:
                hin = t if heat else vu
                h += (hin - h) * h_a
            if not (math.isfinite(t) and abs(t) < 1e4):
                raise RuntimeError("the plant diverged")
            y = t
            if resonance:
                xdd = w0 * w0 * (t - x) - 2 * z * w0 * xd
                xd += xdd * dt
                x += xd * dt
                y = x
            if band is not None:
                m = y if m is None else min(max(m, y - band), y + band)
                y = m
            if drift is not None:
                bias += (drift[0] * t - bias) * drift[1]
                y += bias
            if k >= start and (k + 1) % SUBSTEPS == 0:
                true.append(t)
                read.append(y)
            k += 1
        # The end of the last row is no sample of this recording.
        true, read = true[:n], read[:n]
        if "periodic_force" in e:
            pf = e["periodic_force"]
            read = [y + pf["amplitude_n"] * math.sin(2 * math.pi * tt / pf["period_s"]) for y, tt in zip(read, times)]
        return true, read


def profile(rng, duration_s):
    """Random steps, ramps and holds, with a long high hold followed by idle now and then."""
    rows, u, t = [], rng.uniform(30, 60), 0.0
    while t < duration_s:
        kind = rng.random()
        if kind < 0.55:
            target, hold = rng.uniform(U_MIN, U_MAX), rng.uniform(1.5, 12.0)
            ramp = 0.0
        elif kind < 0.85:
            target, hold = rng.uniform(U_MIN, U_MAX), rng.uniform(1.0, 6.0)
            ramp = abs(target - u) / rng.uniform(5, 60)
        else:
            target, hold, ramp = rng.choice([rng.uniform(85, U_MAX), U_MIN + rng.uniform(0, 5)]), rng.uniform(15, 40), 0.0
        for _ in range(int(ramp / STEP_S)):
            u += (target - u) / max(1, int(ramp / STEP_S))
            rows.append(u)
        u = target
        rows += [u] * int(hold / STEP_S)
        t = len(rows) * STEP_S
    rows = rows[: int(duration_s / STEP_S)]
    return [round(x, 2) for x in rows]


def draw_case(rng, index):
    plant = rng.choice(list(PLANTS))
    with open(PLANTS[plant], "rb") as f:
        params = {k: float(v) for k, v in tomllib.load(f)["model"].items() if k in KEYS}
    if rng.random() < 0.3:  # a perturbed plant: the given model is identified on it (exact)
        params = {k: v * (1 + rng.uniform(-0.05, 0.05)) if k in ("K_T", "B_U", "c", "K_D") else v
                  for k, v in params.items()}
        plant += "~"
    kind = rng.random()
    effects, params_off, artefact = {}, False, None
    if kind < 0.15:
        pass
    elif kind < 0.5:
        name = rng.choice(CATALOGUE)
        effects[name] = draw_effect(rng, name)
    elif kind < 0.65:
        a = rng.choice(CATALOGUE)
        b = rng.choice([x for x in CATALOGUE if x != a])
        effects[a], effects[b] = draw_effect(rng, a), draw_effect(rng, b)
    elif kind < 0.8:
        name = rng.choice(OUTSIDE)
        effects[name] = draw_effect(rng, name)
    elif kind < 0.9:
        params_off = True
    else:
        artefact = rng.choice(ARTEFACTS)
        effects[artefact] = draw_effect(rng, artefact)
    given = dict(params)
    if params_off:
        for k in rng.sample(["K_T", "K_D", "B_U", "c", "K_TD", "B_T"], rng.randint(1, 3)):
            given[k] = params[k] * (1 + rng.choice([-1, 1]) * rng.uniform(0.03, 0.12))
    noise = rng.choice(["white", "white", "coloured", "heteroscedastic"])
    case = {
        "index": index,
        "plant": plant,
        "params": params,
        "given": given,
        "effects": effects,
        "params_off": params_off,
        "artefact": artefact,
        "duration_s": rng.choice([100, 150, 200, 300, 300, 400, 600]),
        "noise": noise,
        "noise_var": rng.uniform(4.0, 9.0),
        "ar": rng.uniform(0.3, 0.8) if noise == "coloured" else 0.0,
        "spikes": rng.random() < 0.3,
        "drops": rng.random() < 0.3,
        "jitter": rng.random() < 0.2,
        "seed": rng.randrange(1 << 30),
    }
    if params_off and DRAW >= 2:
        # Drawn apart from the campaign's sequence, so that every other case is the same as in
        # the first draw.
        own = random.Random(case["seed"] * 2 + 1)
        if own.random() < 0.5:
            name = own.choice(CATALOGUE)
            effects[name] = draw_effect(own, name)
    return case


def klass(case):
    if case["artefact"]:
        return "artefact:" + case["artefact"]
    if case["params_off"]:
        return "parameters + effect" if case["effects"] else "parameters"
    names = sorted(case["effects"])
    if not names:
        return "none"
    if any(n in OUTSIDE for n in names):
        return "outside"
    return "one effect" if len(names) == 1 else "two effects"


def expected(case):
    """The effect names a true claim gives (None: no claim can be true)."""
    if case["artefact"]:
        return None
    return sorted({"discrepancy" if n in OUTSIDE else n for n in case["effects"]})


def in_recall_column(r):
    """Whether a result counts in the recall column: an effect a true claim names, diagnosed
    without error, the given model at least 1.15× the floor (the acceptance's recall)."""
    return bool(expected(r["case"])) and "error" not in r and r["mae_before"] >= 1.15 * r["floor"]


def hetero_scale(t, top):
    """The heteroscedastic noise's σ at thrust `t`, as a share of the case's σ: growing with the
    thrust, from 0.6 at rest to 1.4 at `top`, the recording's highest true thrust (at least 1 N)."""
    return 0.6 + 0.8 * max(0.0, t) / top


def simulate(case, path, throttle=None, seed=None):
    """The case's recording into `path` (CSV); its throttle is the case's random profile, or
    `throttle` (one value per 10 ms) for a second recording of the same engine, whose noise is
    drawn from `seed`. Returns the truth model's held-out MAE."""
    rng = random.Random(case["seed"] if seed is None else seed)
    u = profile(rng, case["duration_s"]) if throttle is None else throttle
    times = [k * STEP_S for k in range(len(u))]
    true, read = Engine(case["params"], case["effects"]).run(times, u)
    sigma = math.sqrt(case["noise_var"])
    top = max(1.0, max(true))
    noise, e = [], 0.0
    for k, t in enumerate(true):
        if case["noise"] == "coloured":
            e = case["ar"] * e + rng.gauss(0, sigma * math.sqrt(1 - case["ar"] ** 2))
        elif case["noise"] == "heteroscedastic":
            e = rng.gauss(0, sigma * hetero_scale(t, top))
        else:
            e = rng.gauss(0, sigma)
        noise.append(e)
    y = [r + n for r, n in zip(read, noise)]
    if case["artefact"] == "clipping":
        top = sorted(y)[int(case["effects"]["clipping"]["quantile"] * (len(y) - 1))]
        y = [min(v, top) for v in y]
    spikes = set()
    if case["spikes"]:
        for k in range(len(y)):
            if rng.random() < 0.002:
                y[k] += rng.choice([-1, 1]) * rng.uniform(25, 60)
                spikes.add(k)
    keep = [not (case["drops"] and rng.random() < 0.01) for _ in y]
    cut = int(0.7 * len(y))
    # The truth model's held-out MAE: the recording against the truth's noise-free reading.
    held = [abs(y[k] - read[k]) for k in range(cut, len(y)) if k not in spikes and keep[k]]
    truth_mae = sum(held) / max(1, len(held))
    with open(path, "w") as f:
        f.write("time_s,throttle_pct,thrust_n\n")
        for k in range(len(y)):
            if keep[k]:
                ts = times[k] + (rng.uniform(-0.002, 0.002) if case["jitter"] else 0.0)
                f.write(f"{ts:.3f},{u[k]:.2f},{y[k]:.2f}\n")
    return truth_mae


def nats_of(case, d, true, top):
    """The log-likelihood ratio (nats) that a difference `d` between two noise-free readings puts
    into the recording under the case's noise model (`true`: the true thrust, and `top` its
    highest, at least 1 N, for the heteroscedastic noise's scale)."""
    var = case["noise_var"]
    if case["noise"] == "coloured":
        # AR(1): the difference whitened, against the innovations' variance.
        a = case["ar"]
        e = [d[0] * math.sqrt(1 - a * a)] + [d[k] - a * d[k - 1] for k in range(1, len(d))]
        return sum(x * x for x in e) / (2 * var * (1 - a * a))
    if case["noise"] == "heteroscedastic":
        return sum(x * x / (2 * var * hetero_scale(t, top) ** 2) for x, t in zip(d, true))
    return sum(x * x for x in d) / (2 * var)


def evidence(case):
    """What each effect of the truth puts into the recording, for an observer who knows everything
    else exactly (the plant, the other effects, the throttle, the noise's law): the log-likelihood
    ratio in nats, over the whole recording, of its noise-free reading with the effect against the
    same without it, under the case's noise model. No diagnosis can draw more from the recording
    about the effect; one that must also fit the effect's values and the other effects' draws
    less. Returns {effect: nats}, for every effect of the truth (artefacts too; None for a clip)."""
    rng = random.Random(case["seed"])
    u = profile(rng, case["duration_s"])
    times = [k * STEP_S for k in range(len(u))]
    true, read = Engine(case["params"], case["effects"]).run(times, u)
    top = max(1.0, max(true))
    out = {}
    for name in case["effects"]:
        rest = {k: v for k, v in case["effects"].items() if k != name}
        _, other = Engine(case["params"], rest).run(times, u)
        # The clip acts on the noisy reading, which this measure does not hold: no figure (null).
        out[name] = None if name == "clipping" else nats_of(case, [a - b for a, b in zip(read, other)], true, top)
    return out


# The lead a claim needs over a rival of other parts: `DISTINCT` of
# crates/ident/src/diagnose/rivals.rs, 10 score units (twice a log-likelihood), in nats.
CLAIM_BAR_NATS = 5.0

# Effects of the throttle path that a look-alike mimics: the look-alike, its one value, and that
# value's unit in the effect's own (a delay of d and a lag of d both hold the answer back by d).
LOOKALIKES = {
    "input_delay": ("actuator_lag", "time_constant_s", "delay_s"),
    "actuator_lag": ("input_delay", "delay_s", "time_constant_s"),
}


def lookalike_evidence(case):
    """What separates each effect of the truth from its look-alike (`LOOKALIKES`), for the same
    observer as `evidence`: the log-likelihood ratio (nats) of the noise-free reading against the
    nearest reading with the effect replaced by its look-alike, the look-alike's one value fitted
    (everything else exact; where the truth holds the look-alike too, the effect is left out and
    the look-alike's value fitted to make up for it). Under `CLAIM_BAR_NATS`, even that observer could not claim the effect over its look-alike by the tool's bar; a diagnosis, which must fit
    the rest too, can do no better. Returns {effect: nats} for the effects that have a look-alike."""
    out = {}
    wanted = [n for n in case["effects"] if n in LOOKALIKES]
    if not wanted:
        return out
    rng = random.Random(case["seed"])
    u = profile(rng, case["duration_s"])
    times = [k * STEP_S for k in range(len(u))]
    true, read = Engine(case["params"], case["effects"]).run(times, u)
    top = max(1.0, max(true))
    for name in wanted:
        other, key, own = LOOKALIKES[name]
        size = case["effects"][name][own] + (case["effects"][other][key] if other in case["effects"] else 0.0)
        rest = {k: v for k, v in case["effects"].items() if k != name}

        def cost(value):
            _, alike = Engine(case["params"], {**rest, other: {key: value}}).run(times, u)
            return nats_of(case, [a - b for a, b in zip(read, alike)], true, top)

        # A log grid from a quarter to four times the effect's size, then golden sections
        # around the best point of the grid.
        grid = [size * 4.0 ** (2.0 * i / 11 - 1.0) for i in range(12)]
        costs = [cost(g) for g in grid]
        i = min(range(len(grid)), key=costs.__getitem__)
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        best = costs[i]
        ratio = (math.sqrt(5) - 1) / 2
        a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        fa, fb = cost(a), cost(b)
        for _ in range(10):
            if fa < fb:
                hi, b, fb = b, a, fa
                a = hi - ratio * (hi - lo)
                fa = cost(a)
            else:
                lo, a, fa = a, b, fb
                b = lo + ratio * (hi - lo)
                fb = cost(b)
        out[name] = min(best, fa, fb)
    return out


# Bins of `evidence` (nats) the report counts recall in.
EVIDENCE_BINS = [0.0, 10.0, 100.0, 1000.0, 10000.0]


def evidence_bins(results):
    """Per bin of `EVIDENCE_BINS`: [effects, named] over the catalogue effects of the recall
    column, and the effects missed as (nats, result, effect)."""
    rows = [[0, 0] for _ in EVIDENCE_BINS]
    missed = []
    for r in results:
        ev = r.get("evidence")
        if ev is None or not in_recall_column(r):
            continue
        for name in r["case"]["effects"]:
            if name in OUTSIDE or ev.get(name) is None:
                continue
            b = max(i for i, lo in enumerate(EVIDENCE_BINS) if ev[name] >= lo)
            hit = r.get("cause") == "missing_physics" and name in r["found"]
            rows[b][0] += 1
            rows[b][1] += hit
            if not hit:
                missed.append((ev[name], r, name))
    return rows, missed


def bin_label(i):
    lo = EVIDENCE_BINS[i]
    hi = EVIDENCE_BINS[i + 1] if i + 1 < len(EVIDENCE_BINS) else None
    return f"{lo:g}–{hi:g}" if hi is not None else f"≥ {lo:g}"


def evidence_section(results):
    """Recall of catalogue effects against what the recording holds of each (`evidence`), and the
    effects missed that an observer knowing the rest would have seen best."""
    rows, missed = evidence_bins(results)
    if not any(n for n, _ in rows):
        return []
    lines = ["", "## Recall against what the recording holds", "",
             "Each catalogue effect of the recall column (the given model ≥ 1.15× the floor), by how much it puts "
             "into the recording: the log-likelihood ratio (nats) of the noise-free reading with it against "
             "without it, for an observer who knows the plant, the other effect and the noise exactly "
             "(`evidence` in scripts/diagnose_campaign.py). No diagnosis can draw more from the recording; one "
             "that must fit the effect and the rest draws less.", "",
             "| evidence (nats) | effects | named | recall |", "|---|---|---|---|"]
    for i, (n, hit) in enumerate(rows):
        lines.append(f"| {bin_label(i)} | {n} | {hit} | {f'{100 * hit / n:.0f} %' if n else '-'} |")
    lines += missed_lines(missed, "The effects missed, most evidence first:", "{:.0f} nats", 25)
    return lines + lookalike_section(results)


def missed_lines(missed, title, nats_format, most):
    """The effects missed as (nats, result, effect), most nats first, at most `most` of them."""
    if not missed:
        return []
    lines = ["", title, ""]
    for nats, r, name in sorted(missed, key=lambda m: -m[0])[:most]:
        case = r["case"]
        lines.append(f"- case {case['index']}: {name} ({nats_format.format(nats)}) beside "
                     f"{[n for n in case['effects'] if n != name] or 'nothing'}; {case['plant']}, "
                     f"{case['noise']} noise, {case['duration_s']} s; said {r.get('cause')} {r.get('found')}")
    return lines


def lookalike_section(results):
    """Recall against what separates each effect from its look-alike (`lookalike_evidence`), and the
    most recall any diagnosis can reach that claims only past the tool's bar."""
    rows = {True: [0, 0], False: [0, 0]}
    total = claimable = 0
    missed = []
    for r in results:
        ev, alike = r.get("evidence"), r.get("lookalike")
        if ev is None or alike is None or not in_recall_column(r):
            continue
        for name in r["case"]["effects"]:
            if name in OUTSIDE or ev.get(name) is None:
                continue
            hit = r.get("cause") == "missing_physics" and name in r["found"]
            total += 1
            apart = ev[name] >= CLAIM_BAR_NATS and alike.get(name, math.inf) >= CLAIM_BAR_NATS
            claimable += apart
            if name in alike:
                rows[alike[name] >= CLAIM_BAR_NATS][0] += 1
                rows[alike[name] >= CLAIM_BAR_NATS][1] += hit
                if not hit:
                    missed.append((alike[name], r, name))
    if not total:
        return []
    lines = ["", "## Recall against what separates an effect from its look-alike", "",
             "A delay and a lag of about its size hold the engine's answer back alike. For each delay and lag of "
             "the recall column: the log-likelihood ratio (nats) of the noise-free reading against the nearest "
             "reading with the effect replaced by the other (its value fitted; everything else exact, for the "
             f"same observer as above; `lookalike_evidence`). Under {CLAIM_BAR_NATS:g} nats (the tool's bar for a "
             "claim over a rival of other parts), not even that observer could claim the effect over its "
             "look-alike.", "",
             "| delays and lags | effects | named | recall |", "|---|---|---|---|"]
    for apart, label in ((True, f"separable (≥ {CLAIM_BAR_NATS:g} nats)"), (False, f"not separable (< {CLAIM_BAR_NATS:g})")):
        n, hit = rows[apart]
        lines.append(f"| {label} | {n} | {hit} | {f'{100 * hit / n:.0f} %' if n else '-'} |")
    lines += ["", f"**The most recall a diagnosis that claims only past the tool's bar can reach here: {claimable} of "
              f"{total} catalogue effects ({100 * claimable / total:.0f} %)**: the effects of the recall column less those "
              f"that put under {CLAIM_BAR_NATS:g} nats into their recording or under {CLAIM_BAR_NATS:g} nats between "
              "themselves and their look-alike, for an observer who knows all else."]
    return lines + missed_lines(missed, "The delays and lags missed, most separable first:",
                                "{:.1f} nats from its look-alike", 15)


def prepare(case, workdir):
    """The case's recording (CSV) and given model (TOML) in `workdir`, and the truth model's
    held-out MAE; a recording kept there from an earlier run of the same draw is reused."""
    csv = Path(workdir) / f"case{case['index']}.csv"
    model = Path(workdir) / f"case{case['index']}.toml"
    truth = Path(workdir) / f"case{case['index']}.truth.json"
    if csv.exists() and truth.exists() and json.loads(truth.read_text()).get("case") == case:
        truth_mae = json.loads(truth.read_text())["truth_mae"]
    else:
        truth_mae = simulate(case, csv)
        truth.write_text(json.dumps({"case": case, "truth_mae": truth_mae}))
    model.write_text("[model]\n" + "".join(f"{k} = {case['given'][k]!r}\n" for k in KEYS))
    return csv, model, truth, truth_mae


def truth_whiteness(jetbench, case, workdir, csv):
    """With the truth itself given as the model (the plant's parameters and the effects at
    their values, in the catalogue's form): the p-value of the whiteness test on its residual,
    or None for a case whose truth the catalogue cannot write (an artefact, physics outside it,
    parameters that are off, for which the given model is not the truth)."""
    if case["artefact"] or case["params_off"] or any(n in OUTSIDE for n in case["effects"]):
        return None
    model = Path(workdir) / f"case{case['index']}.truth.toml"
    text = "[model]\n" + "".join(f"{k} = {case['params'][k]!r}\n" for k in KEYS)
    for name, values in case["effects"].items():
        text += f"[effects.{name}]\n" + "".join(f"{k} = {v!r}\n" for k, v in values.items())
    model.write_text(text)
    out = subprocess.run([jetbench, "diagnose", "--model", str(model), str(csv), "--json"],
                         capture_output=True, text=True)
    model.unlink(missing_ok=True)
    if out.returncode != 0:
        return None
    return json.loads(out.stdout)["before"]["whiteness"]["p_value"]


def run_case(jetbench, case, workdir, keep=False, discriminate=False, truth_given=False, rounds=1):
    csv, model, truth, truth_mae = prepare(case, workdir)
    start = time.monotonic()
    out = subprocess.run([jetbench, "diagnose", "--model", str(model), str(csv), "--json"],
                         capture_output=True, text=True)
    elapsed = time.monotonic() - start
    first = Path(workdir, f"case{case['index']}.json")
    first.write_text(out.stdout)
    result = ({"case": case, "error": out.stderr.strip()[-300:], "time_s": elapsed, "truth_mae": truth_mae}
              if out.returncode != 0 else outcome(case, json.loads(out.stdout), elapsed, truth_mae))
    if discriminate and result.get("cause") == "ambiguous":
        result["second"] = designed(jetbench, case, workdir, csv, model, first, keep, rounds)
    if truth_given:
        result["truth_white_p"] = truth_whiteness(jetbench, case, workdir, csv)
    result["evidence"] = evidence(case)
    if not keep:
        for f in (csv, model, truth, first):
            f.unlink(missing_ok=True)
    return result


def designed(jetbench, case, workdir, csv, model, first, keep=False, rounds=1):
    """The loop an engineer runs on an ambiguous verdict: `jetbench excite --discriminate` designs
    a campaign from the diagnosis, this file's engine records it (the same truth, fresh noise),
    and `jetbench diagnose` takes every recording so far. With `rounds` above 1, a verdict still
    ambiguous is taken round the loop again, from the latest diagnosis. Returns the last
    diagnosis's outcome (or an error, or the design's refusal), graded like the first. With
    `keep`, the designed recordings and the diagnoses stay in `workdir`."""
    start = time.monotonic()
    recordings, diagnoses, diagnosis, designed_s, r = [str(csv)], [], first, 0.0, None
    for k in range(rounds):
        tag = "second" if k == 0 else f"round{k + 2}"
        design = Path(workdir, f"case{case['index']}.{tag}.design.csv")
        recording = Path(workdir, f"case{case['index']}.{tag}.csv")
        excite = [jetbench, "excite", "--discriminate", str(diagnosis), "--model", str(model),
                  "--seed", str(case["index"] + 1000 * k), "--out", str(design)]
        out = subprocess.run(excite, capture_output=True, text=True)
        # When the length is too short, excite says how long would do: the engineer reruns with
        # it, up to ten minutes of bench time. A longer campaign is designed anew and may fall
        # short again (by less): the advice is followed up to three times.
        for _ in range(3):
            longer = re.search(r"rerun with --duration (\d+)", out.stderr)
            if out.returncode == 0 or not longer or int(longer.group(1)) > MAX_DESIGN_S:
                break
            out = subprocess.run(excite + ["--duration", longer.group(1)], capture_output=True, text=True)
        if out.returncode != 0:
            if r is not None:
                # A later round with no design: the last diagnosis stands.
                r["later_refused"] = out.stderr.strip()[-400:]
                break
            return {"case": case, "refused": out.stderr.strip()[-400:], "time_s": time.monotonic() - start}
        with open(design) as f:
            rows = [line.split(",") for line in f.read().splitlines()[1:] if line]
        throttle = [float(row[1]) for row in rows]
        simulate(case, recording, throttle=throttle, seed=case["seed"] + 7919 * (k + 1))
        recordings.append(str(recording))
        designed_s += len(throttle) * STEP_S
        out = subprocess.run([jetbench, "diagnose", "--model", str(model), *recordings, "--json"],
                             capture_output=True, text=True)
        diagnosis = Path(workdir, f"case{case['index']}.{tag}.json")
        diagnosis.write_text(out.stdout)
        diagnoses.append(diagnosis)
        if not keep:
            design.unlink(missing_ok=True)
        if out.returncode != 0:
            r = {"case": case, "error": out.stderr.strip()[-300:]}
            break
        r = outcome(case, json.loads(out.stdout), 0.0, None)
        r["design_s"] = designed_s
        r["rounds"] = k + 1
        if r["cause"] != "ambiguous":
            break
    if not keep:
        for f in recordings[1:]:
            Path(f).unlink(missing_ok=True)
        for f in diagnoses:
            f.unlink(missing_ok=True)
    r["time_s"] = time.monotonic() - start
    return r


def outcome(case, d, elapsed, truth_mae):
    """What the campaign keeps of a diagnosis (`diagnose --json`)."""
    return {
        "case": case,
        "cause": d["cause"],
        "found": sorted(e["name"] for e in d["effects"]),
        "refit": d.get("refit") is not None,
        # Physics claimed on the given parameters, whether they are off as well left open.
        "parameters_open": d.get("parameters_open") is not None,
        # Claimed on the given parameters: how far each could be off with the recording unable
        # to tell ([low, high] per parameter, None for no bound).
        "ranges": (d.get("parameter_ranges") or {}).get("range"),
        # A claim of the part every explanation in play holds: what they hold beside it.
        "undecided": sorted({e for o in d.get("undecided", []) for e in o["effects"]}),
        "undecided_refit": any(o["refit"] for o in d.get("undecided", [])),
        "rivals": [(r["effects"], r["refit"], r["weight"]) for r in d.get("rivals", [])],
        # How far behind each rival was, with and without its penalty per parameter, and whether
        # the search's explanation dominated it: what a rule for claims can be weighed on later.
        "rival_detail": [{k: r.get(k) for k in ("fit_behind", "score_behind", "dominated", "side", "mae_val_n")}
                         for r in d.get("rivals", [])],
        # What the verdict disclosed as able to hide beside the model found.
        "hidden": [{k: p.get(k) for k in ("effect", "probe", "could_hide", "energy", "threshold")}
                   for p in d.get("detectability", []) if p.get("would_show") is False],
        "mae_before": d["mae_before_n"],
        "mae_after": d["mae_after_n"],
        "floor": d["noise_floor_n"],
        "truth_mae": truth_mae,
        "time_s": elapsed,
        "verdict": d["verdict"],
    }


def disclosed(name, values, hidden):
    """True when the diagnosis disclosed that an effect of class `name` with these values could
    hide: a probe of that class that would not show, whose `could_hide` ranges (per key,
    [low, high], None for no bound) hold every value of the effect, with the same keys. The
    ranges lie on the side of the probe where the effect is no more visible (a shorter delay, a
    faster rate limit, a resonance between two hidden probe frequencies, at dampings measured
    hidden); values that cannot be compared with the probe's (another time constant) are not in
    them."""
    for p in hidden or []:
        region = p.get("could_hide") or {}
        if p.get("effect") != name or not values or set(region) != set(values):
            continue
        if all(in_range(v, region[key]) for key, v in values.items()):
            return True
    return False


def in_range(value, bounds):
    """True when `value` lies in `bounds` ([low, high], None for no bound), with a relative
    tolerance for values printed and parsed back (a probe's own value, a range's edge)."""
    lo, hi = bounds
    lo = -math.inf if lo is None else lo
    hi = math.inf if hi is None else hi
    tol = 1e-9 * max(1.0, abs(value))
    return lo - tol <= value <= hi + tol


def left_out(r):
    """The truth's effects a physics claim did not name: (disclosed as able to hide, not)."""
    case, found = r["case"], set(r.get("found", []))
    undecided = set(r.get("undecided", []))
    shown, undisclosed = [], []
    for name, values in case["effects"].items():
        label = "discrepancy" if name in OUTSIDE else name
        if label in found:
            continue
        # A part the claim lists as undecided (an explanation in play holds it) is disclosed.
        if label in undecided or disclosed(name, values, r.get("hidden")):
            shown.append(name)
        else:
            undisclosed.append(name)
    return shown, undisclosed


def within_ranges(r):
    """True when a claim on the given parameters disclosed ranges (`parameter_ranges`) that
    hold the engine's every parameter: parameters off by less than the recording can tell are
    not held against it, as effects disclosed as able to hide are not."""
    ranges = r.get("ranges")
    return bool(ranges) and all(key in ranges and in_range(value, ranges[key])
                                for key, value in r["case"]["params"].items())


def right_about_parameters(r):
    """Where the parameters are off, a claim refits them, leaves them open, or disclosed ranges
    that hold them; where they are as the engine is and the truth is all in the catalogue, it
    does not refit them."""
    case = r["case"]
    if case["params_off"]:
        return bool(r.get("refit") or r.get("undecided_refit") or r.get("parameters_open") or within_ranges(r))
    return not (r.get("refit") and not any(n in OUTSIDE for n in case["effects"]))


def grade(r):
    """(claimed, true claim)."""
    case = r["case"]
    cause = r.get("cause")
    claimed = cause in ("none", "parameters", "missing_physics")
    want = expected(case)
    if not claimed:
        return False, False
    if want is None:
        return True, False
    if cause == "none":
        return True, not want and (not case["params_off"] or within_ranges(r))
    if cause == "parameters":
        return True, not want and case["params_off"]
    # Physics: right about the parameters, every effect named is in the truth, and every effect
    # of the truth not named was disclosed as able to hide at its size.
    if not set(r["found"]) <= set(want):
        return True, False
    if not right_about_parameters(r):
        return True, False
    return True, not left_out(r)[1]


def summarise(results, n, seed, elapsed_s):
    rows = {}
    for r in results:
        k = klass(r["case"])
        rows.setdefault(k, []).append(r)
    lines = [f"# Diagnosis campaign: {n} random cases, seed {seed}", "",
             f"Generated by `scripts/diagnose-campaign.sh {n} {seed}` in {elapsed_s / 60:.1f} min. Every case is "
             "simulated by scripts/diagnose_campaign.py's own engine and diagnosed blind by "
             "the release binary. A claim is `none`, `parameters` or `missing_physics`; `ambiguous`, "
             "`unexplained` and `insufficient_data` are not claims.", "",
             "A physics claim is true when every effect it names is in the truth and every effect of the "
             "truth it leaves out is one its verdict disclosed as able to hide, at a size no smaller than the "
             "truth's. Recall counts the effects named; the next column, effects left out of true claims and "
             "disclosed.", "",
             "| class | cases | claims | true claims | precision | ambiguous | unexplained | insufficient | "
             "recall (given ≥ 1.15× floor) | of catalogue effects | disclosed as undetectable | "
             "MAE after / truth's (claims) | errors |",
             "|" + "---|" * 13]

    def row(name, rs):
        graded = [grade(r) for r in rs]
        claims = sum(c for c, _ in graded)
        true = sum(t for _, t in graded)
        amb = sum(r.get("cause") == "ambiguous" for r in rs)
        unexp = sum(r.get("cause") == "unexplained" for r in rs)
        insuf = sum(r.get("cause") == "insufficient_data" for r in rs)
        errors = sum("error" in r for r in rs)
        present = named = hidden = 0
        # The acceptance's recall is of catalogue effects; physics outside the catalogue,
        # named as a discrepancy, is counted in the recall of every effect.
        catalogue = catalogue_named = 0
        for r in rs:
            if not in_recall_column(r):
                continue
            for w in expected(r["case"]):
                hit = r.get("cause") == "missing_physics" and w in r["found"]
                present += 1
                named += hit
                if w != "discrepancy":
                    catalogue += 1
                    catalogue_named += hit
            if r.get("cause") == "missing_physics" and grade(r)[1]:
                hidden += len(left_out(r)[0])
        ratios = [r["mae_after"] / r["truth_mae"] for r, (c, _) in zip(rs, graded) if c and r["truth_mae"] > 0]
        mae = f"{sum(ratios) / len(ratios):.3f} (worst {max(ratios):.3f})" if ratios else "-"
        prec = f"{100 * true / claims:.1f} %" if claims else "-"
        rec = f"{named}/{present} ({100 * named / present:.0f} %)" if present else "-"
        rec_catalogue = f"{catalogue_named}/{catalogue} ({100 * catalogue_named / catalogue:.0f} %)" if catalogue else "-"
        dis = f"{hidden}/{present}" if present else "-"
        return (f"| {name} | {len(rs)} | {claims} | {true} | {prec} | {amb} ({100 * amb / len(rs):.0f} %) | {unexp} | "
                f"{insuf} | {rec} | {rec_catalogue} | {dis} | {mae} | {errors} |")

    for k in sorted(rows):
        lines.append(row(k, rows[k]))
    lines.append(row("**all**", results))
    lines += ["", "## True claims that leave out an effect they disclose", ""]
    for r in results:
        c, t = grade(r)
        if c and t and r.get("cause") == "missing_physics" and left_out(r)[0]:
            case = r["case"]
            lines.append(f"- case {case['index']} ({klass(case)}, {case['plant']}, {case['noise']} noise, "
                         f"{case['duration_s']} s): truth {case['effects']}; said {r['found']}; disclosed as able "
                         f"to hide or listed as undecided: {', '.join(left_out(r)[0])}")
    partial = [r for r in results if r.get("cause") == "missing_physics" and r.get("undecided")]
    lines += ["", "## Claims of the part every explanation in play holds", "",
              f"The recording could not decide between the explanations in play, but every one of them held the "
              f"physics claimed; what they held beside it is listed as undecided. {len(partial)} such claims, "
              f"{sum(grade(r)[1] for r in partial)} true.", ""]
    for r in partial:
        case = r["case"]
        lines.append(f"- case {case['index']} ({klass(case)}, {case['plant']}, {case['duration_s']} s): truth "
                     f"{case['effects']}; claimed {r['found']}; undecided beside it: {', '.join(r['undecided'])}"
                     f"{' (or the parameters off)' if r.get('undecided_refit') else ''}; "
                     f"{'true' if grade(r)[1] else 'FALSE'}")
    # An ambiguous verdict whose best-weighed explanation wins nearly every resample must say
    # what keeps it from a claim: a weight of 100 % beside "cannot tell apart" reads as a
    # contradiction otherwise.
    leading = [r for r in results if r.get("cause") == "ambiguous"
               and max((w for _, _, w in r.get("rivals") or []), default=0.0) >= 0.95]
    said = sum("but is not claimed" in r.get("verdict", "") for r in leading)
    lines += ["", "## Ambiguous verdicts with a clear favourite", "",
              f"{len(leading)} ambiguous verdicts give one explanation at least 95 % of the resamples; "
              f"{said} of them say why it is not claimed (the rival it does not dominate and by how much its "
              "lead falls short, or the bar of a claim it fails).", ""]
    lines += ["", "## False claims", ""]
    for r in results:
        c, t = grade(r)
        if c and not t:
            case = r["case"]
            lines.append(f"- case {case['index']} ({klass(case)}, {case['plant']}, {case['noise']} noise, "
                         f"{case['duration_s']} s): truth {case['effects'] or ('parameters off' if case['params_off'] else 'none')}; "
                         f"said {r['cause']} {r['found']}{' + refit' if r['refit'] else ''}")
    lines += evidence_section(results)
    lines += designed_section(results)
    lines += truth_section(results)
    lines += ["", "## Time per case", ""]
    times = sorted(r["time_s"] for r in results)
    if times:
        # Nearest rank: the 95th percentile is a time some case took, never below the median.
        median = 0.5 * (times[(len(times) - 1) // 2] + times[len(times) // 2])
        p95 = times[max(math.ceil(0.95 * len(times)) - 1, 0)]
        lines.append(f"median {median:.1f} s, 95th percentile {p95:.1f} s, longest {times[-1]:.1f} s "
                     f"(wall seconds per case, as many cases at a time as `--jobs` said).")
    return "\n".join(lines) + "\n"


def truth_section(results):
    """How often the whiteness test rejects the truth itself (`--truth-given`): its level where
    the model is exact (no effect), and where the catalogue's form of the effects meets this
    file's engine."""
    rows = {}
    for r in results:
        p = r.get("truth_white_p")
        if p is not None:
            n = len(r["case"]["effects"])
            rows.setdefault("no effect" if n == 0 else "one effect" if n == 1 else "two effects", []).append(p)
    if not rows:
        return []
    lines = ["", "## The whiteness test with the truth given", "",
             "Each case whose truth the catalogue can write, diagnosed again with that truth as the model: how often "
             "the whiteness test calls its residual not white (p < 0.01, the test's level).", "",
             "| cases | with the truth given | residual not white |", "|---|---|---|"]
    for name in ("no effect", "one effect", "two effects"):
        ps = rows.get(name, [])
        if ps:
            bad = sum(p < 0.01 for p in ps)
            lines.append(f"| {name} | {len(ps)} | {bad} ({100 * bad / len(ps):.0f} %) |")
    return lines


def designed_section(results):
    """What the designed experiment did to the ambiguous cases (`--discriminate`)."""
    tried = [r for r in results if "second" in r]
    if not tried:
        return []
    seconds = [r["second"] for r in tried]
    graded = [grade(s) for s in seconds]
    true = sum(t for _, t in graded)
    claims = sum(c for c, _ in graded)
    errors = sum("error" in s for s in seconds)
    refused = sum("refused" in s for s in seconds)
    still = sum(s.get("cause") == "ambiguous" for s in seconds)
    other = len(seconds) - claims - still - errors - refused
    first = [grade(r) for r in results]
    all_claims = sum(c for c, _ in first) + claims
    all_true = sum(t for _, t in first) + true
    ambiguous = sum(r.get("cause") == "ambiguous" for r in results)
    lines = ["", "## With the designed experiment", "",
             f"{len(tried)} of the {ambiguous} ambiguous cases (those of the runs with `--discriminate`) got the "
             "loop an engineer would run: `jetbench excite "
             "--discriminate` designed a campaign from the diagnosis (its default throttle limits; the length it "
             f"asked for when 120 s was too short, up to {MAX_DESIGN_S} s), this "
             "file's engine recorded it (the same truth, fresh noise), and `jetbench diagnose` took both recordings.",
             "",
             f"- no experiment designed: {refused} (excite refused and said why: a rival it cannot simulate, or "
             f"more than {MAX_DESIGN_S} s needed);",
             f"- claims: {claims} ({true} true, {claims - true} false); still ambiguous: {still}; unexplained or "
             f"insufficient data: {other}; errors: {errors};",
             f"- precision of claims over the whole campaign, the second answers counted too: {all_true}/{all_claims}"
             + (f" = {100 * all_true / all_claims:.1f} %" if all_claims else ""),
             f"- still ambiguous after it: {still} of the {len(tried)} cases it was run on.",
             *([f"- taken round the loop again (still ambiguous, a campaign designed anew from the latest diagnosis, "
                f"every recording so far diagnosed together; `--rounds`): {again} cases, "
                f"{sum(s.get('rounds', 1) for s in seconds if 'rounds' in s)} designed recordings in all."]
               if (again := sum(s.get("rounds", 1) > 1 for s in seconds)) else []),
             designed_recall(results),
             ""]
    for r, s, (c, t) in zip(tried, seconds, graded):
        case = r["case"]
        what = s.get("cause") or ("no design: " + s["refused"].splitlines()[-1][:160] if "refused" in s
                                  else "error: " + s.get("error", "")[:120])
        lines.append(f"- case {case['index']} ({klass(case)}): truth {case['effects'] or ('parameters off' if case['params_off'] else 'none')}; "
                     f"first {r['rivals'][0][0] if r.get('rivals') else []} leading; with the experiment {what} "
                     f"{s.get('found', '')}{' + refit' if s.get('refit') else ''}"
                     f"{'' if not c else (' (true)' if t else ' (FALSE)')}"
                     + (f", a {s['design_s']:.0f} s design" if "design_s" in s else "")
                     + (f" in {s['rounds']} rounds" if s.get("rounds", 1) > 1 else "") + f", {s['time_s']:.0f} s")
    return lines


def designed_recall(results):
    """The recall of catalogue effects (the acceptance's column) when every ambiguous case the
    experiment was designed for counts the second answer's claim too: what the loop an engineer
    runs delivers, not one recording. An effect counts as named by the second answer only when
    that answer is a true claim naming it."""
    present = first_named = named = 0
    for r in results:
        if not in_recall_column(r):
            continue
        second = r.get("second") or {}
        second_true = grade(second)[1] if "cause" in second else False
        for w in expected(r["case"]):
            if w == "discrepancy":
                continue
            first = r.get("cause") == "missing_physics" and w in r["found"]
            present += 1
            first_named += first
            named += first or (second_true and second.get("cause") == "missing_physics" and w in second["found"])
    if not present:
        return "- recall of catalogue effects: no effect in the recall column."
    return (f"- recall of catalogue effects (given ≥ 1.15× the floor), the second answers counted: {named}/{present} "
            f"= {100 * named / present:.0f} % (first answers alone: {first_named}/{present} = "
            f"{100 * first_named / present:.0f} %).")


def plot_svg(results, path):
    """Outcome per class as stacked bars (SVG, no dependencies): true claims, false claims,
    ambiguous, unexplained, too little data, errors."""
    kinds = [("true claim", "#2a9d43"), ("FALSE claim", "#d62728"), ("ambiguous", "#f2b134"),
             ("unexplained", "#8c8c8c"), ("insufficient_data", "#b5b5e0"), ("error", "#000000")]
    rows = {}
    for r in results:
        c, t = grade(r)
        outcome = ("true claim" if t else "FALSE claim") if c else ("error" if "error" in r else r["cause"])
        rows.setdefault(klass(r["case"]), {}).setdefault(outcome, 0)
        rows[klass(r["case"])][outcome] += 1
    names = sorted(rows)
    width, bar, left, top = 760, 26, 190, 40
    height = top + len(names) * (bar + 10) + 60
    most = max(sum(v.values()) for v in rows.values()) if rows else 1
    scale = (width - left - 20) / most
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
           'font-size="12">', f'<text x="{left}" y="20" font-size="14">Outcome per class ({len(results)} cases)</text>']
    for i, name in enumerate(names):
        y = top + i * (bar + 10)
        out.append(f'<text x="{left - 8}" y="{y + bar * 0.65}" text-anchor="end">{name}</text>')
        x = left
        for kind, colour in kinds:
            n = rows[name].get(kind, 0)
            if n:
                out.append(f'<rect x="{x:.1f}" y="{y}" width="{n * scale:.1f}" height="{bar}" fill="{colour}">'
                           f'<title>{kind}: {n}</title></rect>')
                if n * scale > 14:
                    out.append(f'<text x="{x + n * scale / 2:.1f}" y="{y + bar * 0.65}" text-anchor="middle" '
                               f'fill="white">{n}</text>')
                x += n * scale
    y = top + len(names) * (bar + 10) + 20
    for j, (kind, colour) in enumerate(kinds):
        out.append(f'<rect x="{20 + j * 122}" y="{y}" width="12" height="12" fill="{colour}"/>'
                   f'<text x="{36 + j * 122}" y="{y + 10}">{kind}</text>')
    out.append("</svg>")
    Path(path).write_text("\n".join(out) + "\n")


def plot_evidence_svg(results, path):
    """Recall against what the recording holds (`evidence_bins`) as bars per bin: effects named
    and missed (SVG, no dependencies)."""
    rows, _ = evidence_bins(results)
    width, bar, left, top = 760, 26, 190, 40
    height = top + len(rows) * (bar + 10) + 60
    most = max([n for n, _ in rows] + [1])
    scale = (width - left - 80) / most
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
           'font-size="12">', f'<text x="{left}" y="20" font-size="14">Catalogue effects named, by the evidence '
           'the recording holds of each (nats)</text>']
    for i, (n, hit) in enumerate(rows):
        y = top + i * (bar + 10)
        out.append(f'<text x="{left - 8}" y="{y + bar * 0.65}" text-anchor="end">{bin_label(i)}</text>')
        for x0, count, colour, kind in ((left, hit, "#2a9d43", "named"), (left + hit * scale, n - hit, "#8c8c8c",
                                                                        "missed")):
            if count:
                out.append(f'<rect x="{x0:.1f}" y="{y}" width="{count * scale:.1f}" height="{bar}" fill="{colour}">'
                           f'<title>{kind}: {count}</title></rect>')
        if n:
            out.append(f'<text x="{left + n * scale + 6:.1f}" y="{y + bar * 0.65}">{hit}/{n} ({100 * hit / n:.0f} %)'
                       '</text>')
    y = top + len(rows) * (bar + 10) + 20
    for j, (kind, colour) in enumerate((("named", "#2a9d43"), ("missed", "#8c8c8c"))):
        out.append(f'<rect x="{20 + j * 122}" y="{y}" width="12" height="12" fill="{colour}"/>'
                   f'<text x="{36 + j * 122}" y="{y + 10}">{kind}</text>')
    out.append("</svg>")
    Path(path).write_text("\n".join(out) + "\n")


def self_test():
    """The grader on made-up results: a claim naming the whole truth, one leaving out an effect
    its verdict disclosed as able to hide at the truth's size or listed as undecided, and claims
    leaving out one that was not disclosed, disclosed at a smaller size, or not comparable.
    Returns the failures."""
    lag = {"time_constant_s": 0.3}
    resonance = {"frequency_hz": 3.2, "damping_ratio": 0.09}

    def case(effects, params_off=False):
        return {"index": 0, "effects": effects, "params_off": params_off, "artefact": None}

    def result(effects, found, hidden, params_off=False, refit=False):
        return {"case": case(effects, params_off), "cause": "missing_physics", "found": sorted(found),
                "hidden": hidden, "refit": refit}

    def probe(effect, could_hide):
        return {"effect": effect, "probe": {}, "could_hide": could_hide, "energy": 1.0, "threshold": 50.0}

    band = probe("stand_resonance", {"frequency_hz": [3.0, 5.0], "damping_ratio": [0.02, 0.2]})
    checks = [
        ("the whole truth named", result({"actuator_lag": lag, "stand_resonance": resonance},
                                         ["actuator_lag", "stand_resonance"], []), True),
        ("a resonance left out, disclosed over its frequency and damping",
         result({"actuator_lag": lag, "stand_resonance": resonance}, ["actuator_lag"], [band]), True),
        ("a resonance left out, not disclosed",
         result({"actuator_lag": lag, "stand_resonance": resonance}, ["actuator_lag"], []), False),
        ("a resonance left out, disclosed only above its frequency",
         result({"actuator_lag": lag, "stand_resonance": resonance}, ["actuator_lag"],
                [probe("stand_resonance", {"frequency_hz": [5.0, 8.0], "damping_ratio": [0.02, 0.2]})]), False),
        ("a resonance left out, disclosed at other dampings",
         result({"actuator_lag": lag, "stand_resonance": resonance}, ["actuator_lag"],
                [probe("stand_resonance", {"frequency_hz": [3.0, 5.0], "damping_ratio": [0.1, 0.3]})]), False),
        ("a delay left out, disclosed only up to a smaller delay",
         result({"actuator_lag": lag, "input_delay": {"delay_s": 0.15}}, ["actuator_lag"],
                [probe("input_delay", {"delay_s": [0.0, 0.02]})]), False),
        ("a sensor drift left out, disclosed at another time constant",
         result({"actuator_lag": lag, "sensor_drift": {"gain": 0.01, "time_constant_s": 40.0}}, ["actuator_lag"],
                [probe("sensor_drift", {"gain": [0.0, 0.02], "time_constant_s": [60.0, 60.0]})]), False),
        ("an effect named that is not in the truth", result({"actuator_lag": lag}, ["actuator_lag", "input_delay"],
                                                           [band]), False),
        ("physics outside the catalogue left out", result({"heat_soak": {"loss_per_n": 4e-4, "time_constant_s": 60.0}},
                                                          ["gain_drift"], [band]), False),
        ("a drift left undecided beside the lag claimed",
         dict(result({"actuator_lag": lag, "sensor_drift": {"gain": 0.01, "time_constant_s": 40.0}}, ["actuator_lag"],
                     []), undecided=["sensor_drift"]), True),
        ("a drift left out, another effect left undecided",
         dict(result({"actuator_lag": lag, "sensor_drift": {"gain": 0.01, "time_constant_s": 40.0}}, ["actuator_lag"],
                     []), undecided=["gain_drift"]), False),
        ("an effect claimed beside what is undecided, not in the truth",
         dict(result({"actuator_lag": lag}, ["input_delay"], []), undecided=["actuator_lag"]), False),
        ("parameters off beside a lag: the lag with a refit",
         result({"actuator_lag": lag}, ["actuator_lag"], [], params_off=True, refit=True), True),
        ("parameters off beside a lag: the lag on the given parameters",
         result({"actuator_lag": lag}, ["actuator_lag"], [], params_off=True), False),
        ("parameters off beside a lag: the lag, whether the parameters are off left open",
         dict(result({"actuator_lag": lag}, ["actuator_lag"], [], params_off=True), parameters_open=True), True),
        ("parameters off beside a lag: the lag, a refit undecided beside it",
         dict(result({"actuator_lag": lag}, ["actuator_lag"], [], params_off=True), undecided_refit=True), True),
        ("parameters as the engine is: a lag with a refit",
         result({"actuator_lag": lag}, ["actuator_lag"], [], refit=True), False),
        ("physics outside the catalogue as a discrepancy with a refit",
         result({"heat_soak": {"loss_per_n": 4e-4, "time_constant_s": 60.0}}, ["discrepancy"], [], refit=True),
         True),
    ]
    # Parameters off by less than the recording can tell, beside a lag: the engine's K_D 8 %
    # above the given 1.0, the other parameter exact.
    engine = {"K_D": 1.08, "c": -20.0}

    def on_given(cause, ranges):
        r = dict(result({"actuator_lag": lag} if cause == "missing_physics" else {}, ["actuator_lag"]
                        if cause == "missing_physics" else [], [], params_off=True), cause=cause, ranges=ranges)
        r["case"] = dict(r["case"], params=engine)
        return r

    holds = {"K_D": [0.9, 1.1], "c": [-21.0, -19.0]}
    checks += [
        ("parameters off beside a lag: the lag on the given parameters, ranges that hold the engine's",
         on_given("missing_physics", holds), True),
        ("parameters off beside a lag: the lag on the given parameters, ranges short of the engine's K_D",
         on_given("missing_physics", dict(holds, K_D=[0.95, 1.05])), False),
        ("parameters off beside a lag: ranges without a bound on K_D", on_given("missing_physics", dict(
            holds, K_D=[None, None])), True),
        ("parameters off beside a lag: ranges missing a parameter", on_given("missing_physics", {"c": [-21.0, -19.0]}),
         False),
        ("parameters off: nothing off claimed, ranges that hold the engine's", on_given("none", holds), True),
        ("parameters off: nothing off claimed, no ranges", on_given("none", None), False),
    ]
    failures = []
    for what, r, want in checks:
        claimed, true = grade(r)
        if not claimed or true != want:
            failures.append(f"{what}: graded {'true' if true else 'false'}, should be {'true' if want else 'false'}")
    # The recall with the designed experiment: a lag named by the second answer counts, a delay
    # named by a false second answer does not, nor does one the first answer left ambiguous.
    def ambiguous(effects, second=None):
        r = dict(result(effects, [], []), cause="ambiguous", mae_before=3.0, floor=2.0)
        if second is not None:
            r["second"] = second
        return r

    loop = [ambiguous({"actuator_lag": lag}, result({"actuator_lag": lag}, ["actuator_lag"], [])),
            ambiguous({"input_delay": {"delay_s": 0.1}}, result({"input_delay": {"delay_s": 0.1}},
                                                                 ["input_delay", "gain_drift"], [])),
            ambiguous({"gain_drift": {"per_minute": 0.01}}),
            dict(result({"sensor_offset": {"offset_n": 1.0}}, ["sensor_offset"], []), mae_before=3.0, floor=2.0)]
    said = designed_recall(loop)
    if "3/4" in said or "2/4 = 50 % (first answers alone: 1/4" not in said:
        failures.append(f"recall with the designed experiment on made-up results: {said}")
    return failures


def main():
    global DRAW
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("n", type=int, nargs="?")
    parser.add_argument("seed", type=int, nargs="?")
    parser.add_argument("--self-test", action="store_true", help="check the grader on made-up results and exit")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--jetbench", default=str(ROOT / "target/release/jetbench"))
    parser.add_argument("--out", help="Markdown report (default: stdout)")
    parser.add_argument("--json", help="every case's result, for plots and tests")
    parser.add_argument("--plot", help="SVG of the outcome per class (and, beside it as NAME-evidence.svg, of "
                        "the recall against the evidence each effect put into its recording)")
    parser.add_argument("--deadline-s", type=float, help="stop starting cases after this long; report those done")
    parser.add_argument("--case", type=int, action="append", default=[],
                        help="run only this case of the draw (repeatable): the same case as in the full campaign")
    parser.add_argument("--discriminate", action="store_true",
                        help="on every ambiguous case, run the loop an engineer would: `jetbench excite "
                        "--discriminate` designs a campaign, this file's engine records it, and `jetbench diagnose` "
                        "takes both recordings; the report grades that answer too")
    parser.add_argument("--rounds", type=int, default=1, choices=range(1, 5), metavar="K",
                        help="with --discriminate, take a verdict still ambiguous round the loop again, from the "
                        "latest diagnosis, up to K designed recordings in all (default 1)")
    parser.add_argument("--truth-given", action="store_true",
                        help="also diagnose each case whose truth the catalogue can write with that truth as the "
                        "model, and report how often the whiteness test calls its residual not white")
    parser.add_argument("--from-case", type=int, default=0,
                        help="run the cases of the draw from this index on (to finish a campaign stopped at its "
                        "deadline; --merge joins the parts), beside any --case")
    parser.add_argument("--merge", nargs="+", metavar="JSON",
                        help="do not diagnose: report the results of earlier runs of the same draw (their --json "
                        "files) together, each case once")
    parser.add_argument("--draw", type=int, choices=[1, 2], default=DRAW,
                        help="how the cases are drawn: 1 as before parameters that are off were drawn beside an "
                        "effect (to rerun a campaign made then), 2 (the default) with them")
    parser.add_argument("--keep", help="folder to keep each case's recording (CSV), given model (TOML) and "
                        "diagnosis (JSON) in, to rerun `jetbench diagnose` on it by hand")
    parser.add_argument("--simulate-only", action="store_true",
                        help="only simulate the cases' recordings into --keep (reused by a later run with it)")
    args = parser.parse_args()
    if args.self_test:
        failures = self_test()
        for f in failures:
            print(f"FAILED: {f}", file=sys.stderr)
        print(f"grader self-test: {'passed' if not failures else f'{len(failures)} failed'}", file=sys.stderr)
        sys.exit(1 if failures else 0)
    if args.n is None or args.seed is None:
        parser.error("N and SEED are needed (or --self-test)")
    DRAW = args.draw
    if args.simulate_only and not args.keep:
        parser.error("--simulate-only needs --keep DIR")
    if args.merge:
        results = merged(args.merge)
        rng = random.Random(args.seed)
        drawn = [draw_case(rng, i) for i in range(args.n)]
        foreign = [r["case"]["index"] for r in results
                   if r["case"]["index"] >= args.n or json.loads(json.dumps(drawn[r["case"]["index"]])) != r["case"]]
        if foreign:
            sys.exit(f"--merge: cases {foreign[:5]} are not those of the draw of {args.n} with seed {args.seed}")
        finish(args, results, len(results), sum(r.get("time_s", 0.0) for r in results) / max(args.jobs, 1))
        return
    rng = random.Random(args.seed)
    cases = [draw_case(rng, i) for i in range(args.n)]
    if args.case or args.from_case:
        # Either selects: the cases named, and every case from --from-case on.
        cases = [c for c in cases if c["index"] in args.case or 0 < args.from_case <= c["index"]]
    if args.keep:
        Path(args.keep).mkdir(parents=True, exist_ok=True)
    if args.simulate_only:
        # Only the recordings, into --keep: a later run with the same --keep diagnoses them.
        for c in cases:
            prepare(c, args.keep)
            print(f"case {c['index']} simulated", file=sys.stderr, flush=True)
        return
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp, concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        workdir = args.keep or tmp
        results = []
        futures = [pool.submit(functools.partial(run_case, args.jetbench, workdir=workdir, keep=bool(args.keep),
                                                     discriminate=args.discriminate,
                                                     truth_given=args.truth_given, rounds=args.rounds), c)
                   for c in cases]
        for future in concurrent.futures.as_completed(futures):
            if args.deadline_s and time.monotonic() - start > args.deadline_s:
                for f in futures:
                    f.cancel()
            if future.cancelled():
                continue
            r = future.result()
            results.append(r)
            c, t = grade(r)
            print(f"case {r['case']['index']:4d} {klass(r['case']):22s} {r.get('cause', 'error'):18s} "
                  f"{r.get('found')} {'' if not c else ('true' if t else 'FALSE')} {r['time_s']:.1f} s",
                  file=sys.stderr, flush=True)
            if "second" in r:
                two = r["second"]
                c, t = grade(two)
                print(f"     with the designed experiment: {two.get('cause') or ('no design' if 'refused' in two else 'error'):18s} {two.get('found')} "
                      f"{'' if not c else ('true' if t else 'FALSE')} {two['time_s']:.1f} s", file=sys.stderr, flush=True)
    results.sort(key=lambda r: r["case"]["index"])
    finish(args, results, len(cases), time.monotonic() - start)


def merged(paths):
    """The results of several runs of one draw (their --json files), each case once (the last
    run's), in the order of the draw."""
    by_case = {}
    for path in paths:
        for r in json.loads(Path(path).read_text())["results"]:
            by_case[r["case"]["index"]] = r
    return [by_case[i] for i in sorted(by_case)]


def finish(args, results, drawn, elapsed_s):
    """Report, plot and write the results."""
    # Results of an earlier run without the evidence measure (--merge of older files) get it here.
    lacking = [r for r in results if "evidence" not in r]
    if lacking:
        with concurrent.futures.ProcessPoolExecutor(max(args.jobs, 1)) as pool:
            for r, ev in zip(lacking, pool.map(evidence, [r["case"] for r in lacking])):
                r["evidence"] = ev
    # What separates a delay or a lag from its look-alike: for the recall column only, after the
    # diagnoses (it runs the engine a few dozen times per effect and would slow them).
    lacking = [r for r in results if "lookalike" not in r and "evidence" in r and in_recall_column(r)]
    if lacking:
        with concurrent.futures.ProcessPoolExecutor(max(args.jobs, 1)) as pool:
            for r, alike in zip(lacking, pool.map(lookalike_evidence, [r["case"] for r in lacking])):
                r["lookalike"] = alike
    report = summarise(results, len(results), args.seed, elapsed_s)
    if len(results) < drawn:
        report += f"\nStopped at the deadline: {len(results)} of the {drawn} cases drawn were diagnosed.\n"
    graded = [grade(r) for r in results]
    if args.plot:
        plot_svg(results, args.plot)
        # Beside it, recall against the evidence each effect put into its recording.
        if any(r.get("evidence") for r in results):
            plot_evidence_svg(results, Path(args.plot).with_name(Path(args.plot).stem + "-evidence.svg"))
    if args.json:
        Path(args.json).write_text(json.dumps({
            "cases": len(results),
            "claims": sum(c for c, _ in graded),
            "true_claims": sum(t for _, t in graded),
            "ambiguous": sum(r.get("cause") == "ambiguous" for r in results),
            "errors": sum("error" in r for r in results),
            "results": results,
        }, indent=1, default=str))
    if args.out:
        Path(args.out).write_text(report)
    print(report)
    made = sum(c for c, _ in graded)
    true = sum(t for _, t in graded)
    print(f"precision {true}/{made}", file=sys.stderr)


if __name__ == "__main__":
    main()
