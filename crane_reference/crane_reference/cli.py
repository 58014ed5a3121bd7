"""Command line: ``crane-reference simulate | compile | study | track | loop | urdf | node | plant | controller |
record | modes | analyze``."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml
from tqdm import tqdm

from .control.feedforward import FEEDFORWARDS
from .control.preview_tracking import PREVIEW_FEEDFORWARDS
from .interface.messages import STORAGES
from .model.chain import VARIANTS, build_model
from .model.config import ConfigError, load_config
from .model.urdf import model_to_urdf
from .model.urdf_layout import description_to_urdf
from .motion.programmed_motion import REALISATIONS
from .motion.steps import ANALYSIS_STEP, ONLINE_STEP, PLANT_STEP

CSV_RATE = 1000
"""[Hz] samples per second ``simulate`` writes to CSV/NPZ by default (its figure uses every step)."""
BAG_RATE = 100
"""[Hz] the publish rate of ``simulate --bag`` by default."""


def progress_bar(label: str, total: float) -> tqdm:
    """A tqdm bar over ``total`` seconds of simulated time (shown only when stderr is a terminal); call
    :func:`advance_to` with the simulated time reached."""
    return tqdm(total=total, desc=label, unit="s sim", disable=not sys.stderr.isatty(),
                bar_format="{desc:<9} {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} s [{elapsed}<{remaining}]")


def advance_to(bar: tqdm):
    """A progress callback that moves ``bar`` to the simulated time it is given."""
    return lambda value: bar.update(value - bar.n)


def _variants(choice: str) -> list[str]:
    return list(VARIANTS[::-1]) if choice == "both" else [choice]


def simulate_command(args: argparse.Namespace) -> int:
    if args.bag is not None:
        return export_command(args)
    from .analysis.plotting import figure2
    from .dynamics.cache import cache_counts
    from .motion.simulation import Scenario, simulate
    step = ANALYSIS_STEP if args.step is None else args.step
    rate = CSV_RATE if args.rate is None else args.rate
    stride = round(1.0 / (rate * step)) if rate > 0 else 0
    if stride < 1 or abs(stride * rate * step - 1.0) > 1e-9:
        print(f"crane-reference: --rate {rate}: must be a whole number of steps of {step:g} s apart (e.g. "
              f"{round(1.0 / step)}, {round(0.5 / step)} or {round(0.25 / step)} Hz)", file=sys.stderr)
        return 2
    params = load_config(args.config)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    trajectories = []
    for variant in _variants(args.model):
        scenario = Scenario(params, variant)
        ready, counts = time.perf_counter(), cache_counts()  # the first calls compile the kernels or load them
        start = scenario.equilibrium
        simulate(scenario.motion, start.q, step, step=step)
        ready = time.perf_counter() - ready
        compiled, loaded = np.subtract(cache_counts(), counts)
        wall = time.perf_counter()
        with progress_bar(variant, args.duration) as bar:
            trajectory = simulate(scenario.motion, start.q, args.duration, step=step, progress=advance_to(bar))
        wall = time.perf_counter() - wall
        trajectory.subsampled(stride).to_csv(out / f"{variant}.csv")
        trajectory.subsampled(stride).to_npz(out / f"{variant}.npz")
        trajectories.append(trajectory)  # the figure from every step
        moved = start.q - scenario.model.initial_q
        dependent = ", ".join(f"{scenario.model.joint_names[k]} {moved[k]:+.3e}"
                              for k in scenario.model.dependent_joints)
        print(f"{variant:>8}: kernels ready in {ready:.2f} s ({compiled} compiled, {loaded} loaded from the cache); "
              f"{trajectory.t[-1]:.3f} s simulated in {wall:.2f} s wall "
              f"(real-time factor {trajectory.t[-1] / wall:.1f}), {len(trajectory.t) - 1} steps of {step:g} s; "
              f"max constraint residual {trajectory.residual_distance.max():.2e} m; "
              f"min singular value of K_dc {trajectory.kdc_min_singular_value.min():.3f}; "
              f"equilibrium start: z_E,s = {scenario.z_static:.6f} m, {dependent} rad or m from the initial "
              "configuration, "
              f"holding torque {start.holding_torque:.2e} N m")
    figure2(trajectories, params.actuated, (params.task.ellipse_a, params.task.ellipse_b), out / "figure2.png")
    print(f"wrote {', '.join(f'{t.variant}.csv/.npz' for t in trajectories)} ({rate} samples/s) and figure2.png "
          f"to {out}")
    return 0


def export_command(args: argparse.Namespace) -> int:
    """``crane-reference simulate --bag DIR [--rate HZ] [--bag-storage S] [--bag-version V]``: the bag
    instead of CSV/NPZ/Figure 2, for one model variant (``--model both``, the default, records the
    node's default, flexible)."""
    from .interface import bag, reference_bag

    rate = BAG_RATE if args.rate is None else args.rate
    if not 1 <= rate <= reference_bag.MAX_RATE:
        print(f"crane-reference: --rate {rate}: must be an integer in [1, {reference_bag.MAX_RATE}] Hz",
              file=sys.stderr)
        return 2
    variant = "flexible" if args.model == "both" else args.model
    config = load_config(args.config)
    try:
        writer = bag.BagWriter(args.bag, args.bag_storage, args.bag_version)
    except bag.BagError as error:
        print(f"crane-reference: --bag: {error}", file=sys.stderr)
        return 2
    step = ONLINE_STEP if args.step is None else args.step
    wall = time.perf_counter()
    with writer, progress_bar(variant, args.duration) as bar:
        samples = reference_bag.export_reference(writer, reference_bag.node_stream(config, variant, step), rate,
                                       args.duration, progress=advance_to(bar))
    wall = time.perf_counter() - wall
    counts = ", ".join(f"{topic} {count}" for topic, count in writer.counts.items())
    print(f"{variant}: {samples} samples at {rate} Hz ({args.duration:g} s simulated in {wall:.2f} s wall) "
          f"written to {writer.path} ({writer.storage}, version {writer.version}, "
          f"{writer.size() / 1e6:.2f} MB): {counts}")
    return 0


def study_command(args: argparse.Namespace) -> int:
    from .analysis.study.report import write_report
    from .analysis.study.runner import run_study
    from .analysis.study.spec import StudyError, load_spec

    if args.workers < 1:
        print(f"crane-reference study: --workers {args.workers}: must be >= 1", file=sys.stderr)
        return 2
    try:
        spec = load_spec(args.spec)
    except StudyError as error:
        print(f"crane-reference study: {error}", file=sys.stderr)
        return 2
    try:
        table = run_study(spec, args.out, workers=args.workers, scheduler=args.scheduler,
                          progress=sys.stderr.isatty())
    except KeyboardInterrupt:
        print(f"crane-reference study: interrupted; the finished cases are in {args.out}/results.csv "
              "(run the same command again to go on)", file=sys.stderr)
        return 130
    files = write_report(spec, table, args.out)
    reused = table.attrs["reused"]
    print(f"{len(table)} cases ({int(table['feasible'].sum())} feasible"
          + (f"; {reused} done before, read from {args.out}/results.csv" if reused else "")
          + f"): {', '.join(str(f) for f in files)}")
    return 0


def _by_joint(values: list[str], option: str, size: int, joints: tuple[str, ...]) -> dict[str, tuple[float, ...]]:
    """``JOINT=V1,V2,...`` items (or bare ``V1,...`` for every one of ``joints``, the actuated ones) as floats by
    joint name."""
    out: dict[str, tuple[float, ...]] = {}
    for item in values:
        joint, _, numbers = item.rpartition("=")
        try:
            parsed = tuple(float(x) for x in numbers.split(","))
        except ValueError:
            parsed = ()
        if not 1 <= len(parsed) <= size:
            raise ValueError(f"{option} {item}: expected [JOINT=]V1[,...] with 1 to {size} numbers")
        for name in [joint] if joint else joints:
            if name not in joints:
                raise ValueError(f"{option} {item}: joint {name!r} must be one of {', '.join(joints)}")
            out[name] = parsed
    return out


def track_command(args: argparse.Namespace) -> int:
    from .analysis.tracking.closed_loop import TrackingSpec, run_tracking
    from .analysis.tracking.report import write_report
    from .control.controller import JointGains
    from .motion.simulation import SOLVER_FAILURES

    params = load_config(args.config)
    try:
        given = _by_joint(args.gains, "--gains", 3, params.actuated)
        if any(len(values) < 2 for values in given.values()):
            raise ValueError(f"--gains {' '.join(args.gains)}: give KP,KD[,KI] for each joint")
        gains = {name: JointGains(*values) for name, values in given.items()}
        limits = {name: values[0] for name, values in
                  _by_joint(args.torque_limit, "--torque-limit", 1, params.actuated).items()}
        specs = [TrackingSpec(variant=args.model, realisation=args.realisation, controller=args.controller,
                              bandwidth=args.bandwidth, damping_ratio=args.damping_ratio, gains=gains,
                              feedforward=feedforward, limits=limits, rate=args.rate, duration=args.duration,
                              step=args.step, reference_step=args.reference_step) for feedforward in args.feedforward]
    except ValueError as error:
        print(f"crane-reference track: {error}", file=sys.stderr)
        return 2
    runs = []
    for spec in specs:
        with progress_bar(f"ff {spec.feedforward}", spec.duration) as bar:
            try:
                runs.append(run_tracking(params, spec, progress=advance_to(bar)))
            except SOLVER_FAILURES as failure:
                print(f"crane-reference track: feedforward {spec.feedforward}: the closed loop could not be "
                      f"computed ({type(failure).__name__}: {failure}); an unstable loop makes the torques "
                      "grow until the integrator fails: lower the gains or the bandwidth", file=sys.stderr)
                return 1
    files = write_report(runs, args.out)
    for run in runs:
        s = run.summary()
        print(f"{run.spec.controller} ff {run.spec.feedforward}: E off the ellipse <= "
              f"{s['ellipse_distance_max_m']:.2e} m, height error <= {s['height_error_max_m']:.2e} m, "
              f"tip 40-250 Hz RMS {s['tip_vibration_rms_m']:.2e} m, "
              f"{s['real_time_factor']:.2f}x real time")
    print(f"wrote {', '.join(f.name for f in files)} to {args.out}")
    return 0


def loop_command(args: argparse.Namespace) -> int:
    from .analysis.tracking.closed_loop import TrackingSpec, recorded_run
    from .analysis.tracking.report import write_report
    from .ros.loop import LoopError, run_loop

    try:
        spec = TrackingSpec(variant=args.model, feedforward=args.feedforward, rate=args.rate, duration=args.duration)
    except ValueError as error:
        print(f"crane-reference loop: {error}", file=sys.stderr)
        return 2
    params = load_config(args.config)
    with progress_bar(f"loop ({args.clock_mode})", spec.duration) as bar:
        try:
            recording = run_loop(spec.duration, args.clock_mode, round(spec.rate), spec.variant, args.config or "",
                                 advance_to(bar), spec.feedforward)
        except LoopError as error:
            print(f"crane-reference loop: {error}", file=sys.stderr)
            return 1
    run = recorded_run(params, spec, recording)
    files = write_report([run], args.out)
    s = run.summary()
    print(f"over ROS ({args.clock_mode}): E off the ellipse <= {s['ellipse_distance_max_m']:.2e} m, height error <= "
          f"{s['height_error_max_m']:.2e} m, tip 40-250 Hz RMS {s['tip_vibration_rms_m']:.2e} m, "
          f"{recording.t[-1] / recording.wall:.2f} s of the plant per s of wall time")
    if args.clock_mode == "lockstep":
        config = f" --config {args.config}" if args.config else ""
        print(f"the same loop without ROS (every metric equal but the energy balance): crane-reference track{config} "
              f"--model {spec.variant} --feedforward {spec.feedforward} --rate {args.rate} "
              f"--duration {args.duration:g}")
    print(f"wrote {', '.join(f.name for f in files)} to {args.out}")
    return 0


def compile_command(args: argparse.Namespace) -> int:
    from .control.plant_server import warm_up_plant
    from .stream.warmup import warm_up

    print(f"reference: {warm_up().describe()}; plant: {warm_up_plant().describe()}; "
          f"cache {os.environ['NUMBA_CACHE_DIR']}")
    return 0


def urdf_command(args: argparse.Namespace) -> int:
    params = load_config(args.config)
    if not args.links:
        print(model_to_urdf(build_model(params, args.model)))
        return 0
    text, overlay = description_to_urdf(params)
    print(text)
    if args.overlay:
        overlay = {"urdf": args.urdf_path or f"{params.name}.urdf", **overlay}
        Path(args.overlay).write_text(yaml.safe_dump(overlay, sort_keys=False))
    return 0


def node_command(args: argparse.Namespace, ros_args: list[str]) -> int:
    from .ros.node import main as node_main

    return node_main(ros_args)


def plant_command(ros_args: list[str]) -> int:
    from .ros.plant_node import main as plant_main

    return plant_main(ros_args)


def controller_command(ros_args: list[str]) -> int:
    from .ros.controller_node import main as controller_main

    return controller_main(ros_args)


def record_command(args: argparse.Namespace) -> int:
    from .ros.recorder import record_command as record

    return record(args)


def modes_command(args: argparse.Namespace) -> int:
    from .analysis.modal_report import modes_report

    if not (np.isfinite(args.t) and args.t >= 0.0) or args.count < 1:
        print(f"crane-reference: --t {args.t} must be >= 0 s and --count {args.count} >= 1", file=sys.stderr)
        return 2
    try:
        modes_report(load_config(args.config), args.model, args.t, args.count, args.realisation, args.out)
    except RuntimeError as error:  # the motion up to --t could not be computed (e.g. unstable servo-constraints)
        print(f"crane-reference: {error}", file=sys.stderr)
        return 1
    return 0


def analyze_command(args: argparse.Namespace) -> int:
    from .analysis.vibration_report import analyze

    if not (np.isfinite(args.duration) and args.duration > 0 and args.step > 0):
        print(f"crane-reference: --duration {args.duration} and --step {args.step} must be > 0 s", file=sys.stderr)
        return 2
    analyze(load_config(args.config), args.out, args.duration, args.step)
    print(f"wrote deflection.png, spectra.png, differences.png, efforts.png, summary.json and summary.md to {args.out}")
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="crane-reference", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="run the paper's scenario, write CSV/NPZ and Figure 2")
    s.add_argument("--config", help="crane YAML (default: the packaged config/crane.yaml)")
    s.add_argument("--model", choices=[*VARIANTS, "both"], default="both")
    s.add_argument("--duration", type=float, default=10.0, help="simulated time [s] (default 10)")
    s.add_argument("--out", default="results", help="output directory (default ./results)")
    s.add_argument("--step", type=float, help=f"integrator step [s] (default {ANALYSIS_STEP:g}; with --bag the node's "
                   f"{ONLINE_STEP:g})")
    s.add_argument("--bag", metavar="DIR", help="instead of CSV/NPZ/Figure 2, write the node's topics as a rosbag2 "
                   "bag (new directory DIR), stamped with simulated time; --model both records flexible")
    s.add_argument("--rate", type=int, metavar="HZ", help=f"samples per second written: CSV/NPZ (default "
                   f"{CSV_RATE}: a whole number of steps apart), or with --bag the publish rate (default {BAG_RATE})")
    s.add_argument("--bag-storage", choices=STORAGES, default="mcap", help="--bag: storage (default mcap)")
    s.add_argument("--bag-version", type=int, choices=[9, 8], default=9,
                   help="--bag: metadata version, 9 (Jazzy, default) or 8 (Humble)")
    st = sub.add_parser("study", help="sweep the programmed constraints and crane settings of a study spec (YAML)")
    st.add_argument("spec", help="study spec YAML (see crane_reference/analysis/study/spec.py)")
    st.add_argument("--out", default="results/study", help="output directory (default ./results/study)")
    st.add_argument("--workers", type=int, default=1, help="local worker processes (default 1)")
    st.add_argument("--scheduler", metavar="ADDRESS", help="run the cases on this Dask distributed scheduler")
    tr = sub.add_parser("track", help="closed loop: the actuated crane (no programmed constraints) following the "
                        "reference under joint PD/PID with optional feedforward (the rigid crane's inverse "
                        "dynamics, or the reference's constraint forces as the node's preview carries them)")
    tr.add_argument("--config", help="crane YAML (default: the packaged config/crane.yaml)")
    tr.add_argument("--model", choices=VARIANTS, default="flexible", help="crane (plant and reference)")
    tr.add_argument("--realisation", choices=REALISATIONS, default="ideal",
                    help="the reference's constraint realisation (ideal: what the node publishes)")
    tr.add_argument("--controller", choices=["pd", "pid"], default="pd")
    tr.add_argument("--bandwidth", type=float, default=2.0, help="closed-loop bandwidth per joint [Hz] (default 2)")
    tr.add_argument("--damping-ratio", type=float, default=0.7, help="closed-loop damping ratio (default 0.7)")
    tr.add_argument("--gains", nargs="*", default=[], metavar="[JOINT=]KP,KD[,KI]",
                    help="gains instead of the bandwidth's, per actuated joint (the paper's crane: column_slew, "
                         "boom_luff, knuckle) or for all")
    tr.add_argument("--feedforward", nargs="+", choices=FEEDFORWARDS, default=["none", "rigid"],
                    help="one run per choice (default: none and rigid; reference: the node's preview efforts)")
    tr.add_argument("--torque-limit", nargs="*", default=[], metavar="[JOINT=]N_M", help="actuator torque limits")
    tr.add_argument("--rate", type=float, default=1000.0, help="controller rate [Hz] (default 1000)")
    tr.add_argument("--duration", type=float, default=5.0, help="simulated time [s] (default 5)")
    tr.add_argument("--step", type=float, default=PLANT_STEP,
                    help=f"the plant's integrator step [s] (default {PLANT_STEP:g})")
    tr.add_argument("--reference-step", type=float,
                    help=f"the reference's integrator step [s], a divisor of --step (default: the node's, "
                         f"{ONLINE_STEP:g}, where it divides --step, else --step)")
    tr.add_argument("--out", default="results/tracking", help="output directory (default ./results/tracking)")
    lo = sub.add_parser("loop", help="the closed loop over ROS without launch: the reference node, the plant and the "
                        "example controller as processes; records the plant and writes track's summary and figure")
    lo.add_argument("--config", help="crane YAML (default: the packaged config/crane.yaml)")
    lo.add_argument("--model", choices=VARIANTS, default="flexible", help="crane (plant and reference)")
    lo.add_argument("--clock-mode", choices=["lockstep", "realtime"], default="lockstep",
                    help="lockstep: the plant's /clock paces the three, deterministically (default); realtime: the "
                         "wall clock")
    lo.add_argument("--rate", type=int, default=1000, help="control rate [Hz] (default 1000)")
    lo.add_argument("--duration", type=float, default=5.0, help="seconds of the plant's time (default 5)")
    lo.add_argument("--feedforward", choices=PREVIEW_FEEDFORWARDS, default="none",
                    help="the controller's feedforward: none (default), or reference: the preview's efforts")
    lo.add_argument("--out", default="results/loop", help="output directory (default ./results/loop)")
    sub.add_parser("compile", help="compile the numba kernels ahead of the first run (fills the cache; "
                   "`colcon build` does it for the package it installs; run it after `pip install` or "
                   "`colcon build --symlink-install`)")
    u = sub.add_parser("urdf", help="print the URDF of a model variant (every coordinate a joint: for "
                       "robot_state_publisher), or with --links the URDF of the crane's links as described")
    u.add_argument("--config")
    u.add_argument("--model", choices=VARIANTS, default="flexible")
    u.add_argument("--links", action="store_true", help="the links as described (a flexible link as one link), "
                   "the form a crane file's `urdf` takes")
    u.add_argument("--overlay", metavar="FILE", help="with --links: also write the overlay that makes it this crane")
    u.add_argument("--urdf-path", metavar="PATH", help="with --overlay: the overlay's `urdf` (default <name>.urdf)")
    sub.add_parser("node", help="run the ROS 2 node (arguments after 'node' go to ROS)", add_help=False)
    sub.add_parser("plant", help="run the ROS 2 plant node: the actuated crane under effort commands (arguments "
                   "after 'plant' go to ROS)", add_help=False)
    sub.add_parser("controller", help="run the example ROS 2 controller node for the plant (arguments after "
                   "'controller' go to ROS)", add_help=False)
    r = sub.add_parser("record", help="record topics to a rosbag2 bag (default: every topic the crane_reference "
                       "node publishes) until SIGINT/SIGTERM or --duration")
    r.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (default: every topic --node "
                   "publishes)")
    r.add_argument("--node", default="/crane_reference", metavar="NAME",
                   help="without TOPICs, record what this node publishes, as the ROS graph shows it "
                   "(default /crane_reference)")
    r.add_argument("-o", "--output", metavar="DIR", help="new bag directory (default rosbag2_YYYY_MM_DD-HH_MM_SS)")
    r.add_argument("--storage", choices=STORAGES, default="mcap", help="storage (default mcap)")
    r.add_argument("--version", type=int, choices=[9, 8], default=9,
                   help="metadata version, 9 (Jazzy, default) or 8 (Humble)")
    r.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: at SIGINT/SIGTERM)")
    m = sub.add_parser("modes", help="natural frequencies and mode shapes of the constrained crane at time t")
    m.add_argument("--config")
    m.add_argument("--t", type=float, default=0.0, help="time of the motion [s] (default 0: the static equilibrium)")
    m.add_argument("--model", choices=VARIANTS, default="flexible")
    m.add_argument("--count", type=int, default=12, help="modes in the table and the drawing (default 12)")
    m.add_argument("--realisation", choices=REALISATIONS, default="ideal", help="constraint realisation")
    m.add_argument("--out", default="results", help="directory of the PNG (default ./results)")
    a = sub.add_parser("analyze", help="boom vibration, spectra vs modes, rigid vs flexible, both realisations")
    a.add_argument("--config")
    a.add_argument("--out", default="results/analysis", help="output directory (default ./results/analysis)")
    a.add_argument("--duration", type=float, default=10.0, help="simulated time [s] (default 10)")
    a.add_argument("--step", type=float, default=ANALYSIS_STEP, help=f"integrator step [s] (default {ANALYSIS_STEP:g})")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["node"]:
        return node_command(argparse.Namespace(), argv[1:])
    if argv[:1] == ["plant"]:
        return plant_command(argv[1:])
    if argv[:1] == ["controller"]:
        return controller_command(argv[1:])
    args = parser().parse_args(argv)
    if args.command == "simulate" and not (np.isfinite(args.duration) and args.duration > 0):
        parser().error(f"--duration {args.duration}: must be a finite number of seconds > 0")
    try:
        return {"simulate": simulate_command, "urdf": urdf_command, "record": record_command, "modes": modes_command,
                "analyze": analyze_command, "compile": compile_command, "study": study_command,
                "track": track_command, "loop": loop_command}[args.command](args)
    except ConfigError as error:
        print(f"crane-reference: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
