"""Where the faithful hand's physics step spends its time, phase by phase, and what it collides
(issue 64: the GPU campaign runs ~4x slower in contact than with the capsule hand of 2026-11-23).

A trained run's own env config (its task, objects, representation, physics; ``--envs`` envs) is
driven by the run's policy (deterministic actions) for ``--advance`` env steps, untimed, so that
the hands grasp; then, at those same states (each configuration's physics loads them: a variant
may change geometry, contact and solver settings, not the state's size), for the run's
configuration and each ``--variant`` (``"KEY=VALUE ..."``, repeatable):

- **MuJoCo C** (``--backend cpu``): in each of ``--rounds`` rounds, ``--steps`` physics steps
  of every env, one thread, with MuJoCo's own phase timers (``MjData.timer``): kinematics,
  broadphase, narrowphase, constraint build, velocity, actuation, constraint solver (its no-slip
  pass included), integration; in microseconds per env and physics step.
- **MuJoCo Warp** (``--backend warp``, ``--device cpu`` or ``cuda``): the phases of one physics
  step of all worlds at once, in each round each repeated ``--repeats`` times between device
  synchronizations (eager launches, no CUDA graph): the whole step, collision (its broadphase
  alone), constraint build, the solver (its no-slip pass alone); in milliseconds per physics
  step of all worlds (what is left of the step: kinematics, inertia, velocity, actuation,
  integration). Also the
  broadphase's **candidate pairs** (what the narrowphase is launched on), by geom-type pair and
  by part pair, and the contact and constraint buffers per world against the most any world used.
  On CUDA, MuJoCo Warp's own event trace of one step is printed below (its ``event_scope``
  functions, nested), where ``convex_narrowphase`` (GJK/EPA on hulls) and
  ``primitive_narrowphase`` show apart.

Both print the contacts per env by part pair (``hand``: finger/thumb hulls and palm, ``arm``,
``object``: the object's convex pieces, ``static``: table, bin), by geom-type pair and by hand
link (which links touch anything: where the hulls matter), and the constraint rows per env. The
configurations are timed in alternating rounds and each phase's time is its least over the
rounds (a busy machine only adds), each step's time also as a ratio to the run's own (the
baseline): compare configurations within one run, not across runs.

    python bench/step_phases.py --policy RUN [--backend cpu|warp] [--device cpu|cuda] \\
        [--envs 32] [--advance 150] [--steps 10] [--repeats 5] [--rounds 3] [--data-dir DIR] \\
        [--variant "robot.hand_geometry=capsules" ...]
"""

from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path

import mujoco
import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from trainer.assets.collision import BIT_ARM, BIT_HAND, BIT_OBJECT, BIT_STATIC
from trainer.assets.scene import hand_geoms
from trainer.config import check_backend, check_device, dotted_overrides, override
from trainer.config_keys import parse_sets
from trainer.errors import TrainerError
from trainer.tasks import GraspTask, make_env
from trainer.training.checkpoint import load_agent

T = mujoco.mjtTimer
C_PHASES = (
    ("kinematics", (T.mjTIMER_POS_KINEMATICS, T.mjTIMER_POS_INERTIA)),
    ("broadphase", (T.mjTIMER_COL_BROAD,)),
    ("narrowphase", (T.mjTIMER_COL_NARROW,)),
    ("constraint build", (T.mjTIMER_POS_MAKE, T.mjTIMER_POS_PROJECT)),
    ("velocity", (T.mjTIMER_VELOCITY,)),
    ("actuation", (T.mjTIMER_ACTUATION,)),
    ("solver+noslip", (T.mjTIMER_CONSTRAINT,)),
    ("integration", (T.mjTIMER_ADVANCE,)),
)
"""MuJoCo C's phases as the sums of its timers (``mjtTimer``); the step's total is
``mjTIMER_STEP``, and what no timer covers is reported as ``other``."""
PARTS = ((BIT_HAND, "hand"), (BIT_ARM, "arm"), (BIT_OBJECT, "object"), (BIT_STATIC, "static"))
"""A geom's part: the first of these collision bits (``trainer.assets.collision``) its
``contype`` holds."""


def geom_parts(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) str: each geom's part (``PARTS``), ``-`` for geoms that collide with nothing."""
    out = np.full(model.ngeom, "-", dtype=object)
    for bit, name in reversed(PARTS):  # the first bit in PARTS wins
        out[(model.geom_contype & bit) != 0] = name
    colliding = (model.geom_contype | model.geom_conaffinity) != 0
    out[colliding & (model.geom_bodyid == 0)] = "static"  # the world's geoms: table, bin, floor
    return out


def geom_type_names(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) str: each geom's type, ``mesh``, ``box``, ``plane``, ..."""
    names = {int(t): mujoco.mjtGeom(t).name.removeprefix("mjGEOM_").lower()
             for t in np.unique(model.geom_type)}
    return np.array([names[int(t)] for t in model.geom_type], dtype=object)


def hand_links(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) str: the body name of each hand geom (``palm``, ``if_distal``, ...), ``-`` for
    the rest."""
    out = np.full(model.ngeom, "-", dtype=object)
    for g in hand_geoms(model):
        if model.geom_contype[g] or model.geom_conaffinity[g]:  # it collides
            out[g] = model.body(int(model.geom_bodyid[g])).name
    return out


def count_links(pairs: np.ndarray, links: np.ndarray, into: collections.Counter) -> None:
    """Add each contact of a hand geom with an object or fixture to ``into`` under the hand
    link's name (hand-hand contacts are not counted)."""
    a, b = links[pairs[:, 0]], links[pairs[:, 1]]
    one = (a == "-") ^ (b == "-")
    into.update(np.where(a == "-", b, a)[one])


def count_pairs(pairs: np.ndarray, labels: np.ndarray, into: collections.Counter) -> None:
    """Add each (geom1, geom2) row of ``pairs`` (n, 2) to ``into`` under its labels' sorted
    pair, e.g. ``hand-object``."""
    a, b = labels[pairs[:, 0]], labels[pairs[:, 1]]
    first = np.where(a <= b, a, b)
    second = np.where(a <= b, b, a)
    into.update(f"{x}-{y}" for x, y in zip(first, second, strict=True))


def make_variant(cfg, extra: dict, args: argparse.Namespace) -> GraspTask:
    """The run's env config with ``extra`` over it and ``--envs`` envs."""
    base = {"num_envs": args.envs, "backend": args.backend, "device": args.device}
    if args.data_dir:
        base["data_dir"] = args.data_dir
    return make_env(override(cfg.env, {**base, **extra}, {}))


def drive(env: GraspTask, agent, steps: int) -> None:
    """``steps`` env steps of the policy's deterministic actions from a reset."""
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(steps):
            td = agent.actor(td)
            _, td = env.step_and_maybe_reset(td)


STATE = int(mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_CTRL
            | mujoco.mjtState.mjSTATE_MOCAP_POS | mujoco.mjtState.mjSTATE_MOCAP_QUAT)
"""What a variant's MuJoCo C data takes over from the driven env: the physics and the controls."""


def c_phases(source: GraspTask, env: GraspTask, steps: int) -> tuple[dict[str, float], dict]:
    """MuJoCo C, one thread, ``env``'s models at ``source``'s current states and controls:
    (microseconds per env and physics step by phase, with ``step`` and ``other``; counts:
    contacts by part pair and by type pair, constraint rows, per env and step) over ``steps``
    physics steps of every env."""
    totals = collections.Counter()
    parts_count, types_count = collections.Counter(), collections.Counter()
    links_count = collections.Counter()
    rows, most_contacts, most_rows = 0, 0, 0
    labels: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for i in range(env.num_envs):
        src_model, src_data = source.backend.snapshot(i)  # a copy: the env is left as it was
        model = env.backend.models[int(env.backend.env_layout[i])]
        state = np.empty(mujoco.mj_stateSize(src_model, STATE))
        mujoco.mj_getState(src_model, src_data, state, STATE)
        data = mujoco.MjData(model)
        mujoco.mj_setState(model, data, state, STATE)
        mujoco.mj_forward(model, data)
        if id(model) not in labels:
            labels[id(model)] = geom_parts(model), geom_type_names(model), hand_links(model)
        parts, types, links = labels[id(model)]
        before = {t: data.timer[t].duration for _, ts in C_PHASES for t in ts}
        step_before = data.timer[T.mjTIMER_STEP].duration
        for _ in range(steps):
            mujoco.mj_step(model, data)
            pairs = np.asarray(data.contact.geom[: data.ncon]).reshape(-1, 2)
            count_pairs(pairs, parts, parts_count)
            count_pairs(pairs, types, types_count)
            count_links(pairs, links, links_count)
            rows += data.nefc
            most_contacts, most_rows = max(most_contacts, data.ncon), max(most_rows, data.nefc)
        for name, ts in C_PHASES:
            totals[name] += sum(data.timer[t].duration - before[t] for t in ts)
        totals["step"] += data.timer[T.mjTIMER_STEP].duration - step_before
    n = env.num_envs * steps
    times = {k: 1e6 * v / n for k, v in totals.items()}
    times["other"] = times["step"] - sum(times[name] for name, _ in C_PHASES)
    counts = {"parts": {k: v / n for k, v in parts_count.items()},
              "types": {k: v / n for k, v in types_count.items()}, "rows": rows / n,
              "links": {k: v / n for k, v in links_count.items()},
              "buffers": {"contacts, most in an env": most_contacts,
                          "rows, most in an env": most_rows}}
    return times, counts


def warp_phases(env: GraspTask, repeats: int) -> tuple[dict[str, float], dict, dict | None]:
    """MuJoCo Warp at the worlds' current states: (milliseconds per physics step of all worlds
    by phase; counts per env: contacts and candidate pairs by part and type pair, constraint
    rows; on CUDA MuJoCo Warp's event trace of one step, else None)."""
    import mujoco_warp as mjw
    import warp as wp
    from mujoco_warp._src import collision_driver, solver, warp_util  # pinned: mujoco-warp 4.0.0

    backend = env.backend
    m, d, model = backend.m, backend.d, backend.merged
    device = backend._wp_device

    def timed(fn) -> float:
        wp.synchronize_device(device)
        start = time.perf_counter()
        for _ in range(repeats):
            fn()
        wp.synchronize_device(device)
        return 1e3 * (time.perf_counter() - start) / repeats

    broadphase = (mjw.nxn_broadphase if m.opt.broadphase == mjw.BroadphaseType.NXN
                  else mjw.sap_broadphase)
    with wp.ScopedDevice(device):
        ctx = collision_driver.create_collision_context(d.naconmax)

        def broad() -> None:
            d.ncollision.zero_()
            broadphase(m, d, ctx)

        mjw.forward(m, d)
        times = {"collision": timed(lambda: mjw.collision(m, d)),
                 "broadphase": timed(broad)}
        # counts at this state: the broadphase's candidates, the contacts, the rows
        broad()
        ncand = int(d.ncollision.numpy()[0])
        candidates = ctx.collision_pair.numpy()[:ncand]
        mjw.forward(m, d)
        nacon = int(d.nacon.numpy()[0])
        contacts = d.contact.geom.numpy()[:nacon]
        per_world = np.bincount(d.contact.worldid.numpy()[:nacon], minlength=env.num_envs)
        nefc = d.nefc.numpy()
        rows = float(nefc.sum())
        times["constraint build"] = timed(lambda: mjw.make_constraint(m, d))
        mjw.forward(m, d)
        times["solver+noslip"] = timed(lambda: mjw.solve(m, d))
        times["noslip"] = timed(lambda: solver.noslip(m, d)) if m.opt.noslip_iterations else 0.0
        times["step"] = timed(lambda: mjw.step(m, d))
        trace = None
        if device.is_cuda:
            with warp_util.EventTracer() as tracer:
                mjw.step(m, d)
                wp.synchronize_device(device)
                trace = tracer.trace()
    times["narrowphase"] = times["collision"] - times["broadphase"]
    parts, types, links = geom_parts(model), geom_type_names(model), hand_links(model)
    by_link, candidate_links = collections.Counter(), collections.Counter()
    count_links(contacts.reshape(-1, 2), links, by_link)
    count_links(candidates.reshape(-1, 2), links, candidate_links)
    counts: dict = {"links": {k: v / env.num_envs for k, v in by_link.items()},
                    "candidate links": {k: v / env.num_envs for k, v in candidate_links.items()},
                    "rows": rows / env.num_envs,
                    "buffers": {"contacts per world (buffer)": backend.contacts,
                                "contacts, most in a world": int(per_world.max()),
                                "rows per world (buffer)": backend.constraints,
                                "rows, most in a world": int(nefc.max())}}
    for key, pairs in (("candidates", candidates), ("contacts", contacts)):
        by_part, by_type = collections.Counter(), collections.Counter()
        count_pairs(pairs.reshape(-1, 2), parts, by_part)
        count_pairs(pairs.reshape(-1, 2), types, by_type)
        counts[key] = {"parts": {k: v / env.num_envs for k, v in by_part.items()},
                       "types": {k: v / env.num_envs for k, v in by_type.items()}}
    return times, counts, trace


def print_trace(trace: dict, depth: int = 0) -> None:
    """MuJoCo Warp's event trace (``EventTracer.trace()``): name, milliseconds, nested."""
    for name, (events, sub) in trace.items():
        print(f"  {'  ' * depth}{name:<{40 - 2 * depth}} {sum(events):9.3f} ms"
              f"{f' ({len(events)} calls)' if len(events) > 1 else ''}")
        print_trace(sub, depth + 1)


def table(title: str, rows: dict[str, dict[str, float]], fmt: str) -> None:
    """One column per configuration, one row per key (the keys of every configuration)."""
    keys = sorted({k for r in rows.values() for k in r}, key=lambda k: -max(
        r.get(k, 0.0) for r in rows.values()))
    labels = list(rows)
    print(f"\n{title}")
    print(f"{'':>24}" + "".join(f"{i:>12}" for i in range(len(labels))))
    for key in keys:
        print(f"{key:>24}" + "".join(format(rows[lab].get(key, 0.0), fmt).rjust(12)
                                     for lab in labels))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", required=True, metavar="RUN", help="a trained run's folder")
    parser.add_argument("--backend", default="cpu", choices=("cpu", "warp"))
    parser.add_argument("--device", default="cpu", help="warp: cpu, or cuda for a GPU")
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--advance", type=int, default=150,
                        help="untimed policy steps first, so that the hands grasp")
    parser.add_argument("--steps", type=int, default=10, help="cpu: physics steps per env")
    parser.add_argument("--repeats", type=int, default=5, help="warp: calls of each phase")
    parser.add_argument("--rounds", type=int, default=3,
                        help="alternating rounds over the configurations (times: the least)")
    parser.add_argument("--data-dir", default=None, help="default: the run's data_dir")
    parser.add_argument("--variant", dest="variants", action="append", default=[],
                        metavar="'KEY=VALUE ...'",
                        help="one more configuration per use (several KEY=VALUE in one string)")
    args = parser.parse_args(argv)
    try:
        configs = [("the run's own", {})] + [
            (text, dotted_overrides(parse_sets(text.split(), "--variant")))
            for text in args.variants]
        check_backend(args.backend)
        check_device(args.device, f"--device {args.device}", "use --device cpu")
        cfg, agent = load_agent(Path(args.policy), args.device)
    except (TrainerError, FileNotFoundError) as exc:
        raise SystemExit(f"step_phases: {exc}") from None
    torch.set_num_threads(1)
    envs = {}
    for label, extra in configs:
        try:
            envs[label] = make_variant(cfg, extra, args)
        except TrainerError as exc:
            raise SystemExit(f"step_phases: {label}: {exc}") from None
    first = next(iter(envs.values()))
    drive(first, agent, args.advance)
    states = first.backend.state_dict()
    for label, env in envs.items():
        if (env.backend.nq, env.backend.nv, env.backend.nu) != (
                first.backend.nq, first.backend.nv, first.backend.nu):
            raise SystemExit(f"step_phases: {label}: its physics state differs in size from the "
                             "run's own; a variant may change geometry, contact and solver "
                             "settings only")
    # Rounds alternate the configurations, so that a busy moment of the machine hits them all;
    # each time is the least over the rounds (what the work costs when nothing interrupts it:
    # other processes only ever add), the counts are the last round's. Every round starts from
    # the same states.
    rounds: dict[str, list[dict[str, float]]] = collections.defaultdict(list)
    parts: dict[str, dict[str, float]] = {}
    types: dict[str, dict[str, float]] = {}
    links: dict[str, dict[str, float]] = {}
    extra_rows: dict[str, dict[str, dict]] = {}
    traces = {}
    for _ in range(args.rounds):
        for label, env in envs.items():
            if args.backend == "cpu":
                times, counts = c_phases(first, env, args.steps)
                parts[label], types[label] = counts["parts"], counts["types"]
                extra_rows.setdefault("buffers", {})[label] = counts["buffers"]
            else:
                env.backend.load_state_dict(states)
                times, counts, traces[label] = warp_phases(env, args.repeats)
                parts[label] = counts["contacts"]["parts"]
                types[label] = counts["contacts"]["types"]
                for key in ("candidates by part", "candidates by type"):
                    kind, by = key.split(" by ")
                    extra_rows.setdefault(key, {})[label] = counts[kind][f"{by}s"]
                extra_rows.setdefault("candidates by hand link", {})[label] = counts[
                    "candidate links"]
                extra_rows.setdefault("buffers", {})[label] = counts["buffers"]
            parts[label]["constraint rows"] = counts["rows"]
            links[label] = counts["links"]
            rounds[label].append(times)
    times = {label: {k: min(r[k] for r in rs) for k in rs[0]} for label, rs in rounds.items()}
    for env in envs.values():
        env.close()
    print(f"{args.policy}: {cfg.env.task}, repr {cfg.env.representation}, {args.envs} envs, "
          f"{args.backend} on {args.device}, after {args.advance} policy steps")
    for i, (label, _) in enumerate(configs):
        print(f"  [{i}] {label}")
    unit = ("microseconds per env and physics step (MuJoCo C, one thread)" if args.backend == "cpu"
            else "milliseconds per physics step of all worlds (MuJoCo Warp)")
    table(f"time by phase, {unit}", times, ".1f" if args.backend == "cpu" else ".3f")
    base = times[configs[0][0]]["step"]  # the baseline: the run's own, timed in the same rounds
    print("step / the run's own".rjust(24)
          + "".join(f"{t['step'] / base:>12.2f}" for t in times.values()))
    table("contacts per env by part pair (and constraint rows)", parts, ".2f")
    table("contacts per env by geom-type pair", types, ".2f")
    table("contacts per env of each hand link with an object or fixture", links, ".2f")
    for title, rows in extra_rows.items():
        if title == "buffers":
            table("contact and constraint buffers: sized (warp) and most used", rows, "d")
        elif title.endswith("link"):
            table("broadphase candidates per env of each hand link with an object or fixture",
                  rows, ".2f")
        else:
            table(f"broadphase {title} pair, per env", rows, ".2f")
    for label, trace in traces.items():
        if trace:
            print(f"\nMuJoCo Warp's event trace of one step, {label}:")
            print_trace(trace)


if __name__ == "__main__":
    main()
