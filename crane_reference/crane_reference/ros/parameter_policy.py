"""What the node's parameters mean for the reference server and the messages, decided apart from the node:
the messages' settings and the preview a set of values gives, the reason to refuse a change (the on-set
callback) and the server calls that apply an accepted one (the post-set callback).
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.parameter import Parameter

from ..base.health import StartupError
from ..model.description import CraneDescription
from ..motion.simulation import SOLVER_FAILURES
from ..stream.served import CommandRefusedError, Preview
from ..stream.server import ReferenceServer
from ..stream.solver import LocalSolver, SolverClient, SolverProcess
from ..stream.solver_messages import StreamSpec
from ..stream.targets import UnreachableTargetError
from .parameter_spec import ParameterError, check
from .parameters import COMMANDING_PARAMETERS, SPECS, TARGET_PARAMETERS, NodeParameters
from .publishing import PublishSettings
from .service_replies import sample_named

MESSAGE_PARAMETERS = ("frame_id", "frame_prefix", "preview.joints", "preview.effort")
"""The parameters that change the messages' :class:`~.publishing.PublishSettings`."""


def publish_settings(params: NodeParameters, joint_names: tuple[str, ...],
                     preview_joints: tuple[str, ...] | None = None) -> PublishSettings:
    """The messages' settings of ``params``, with the preview's joints ``preview_joints`` (default: the
    parameter's); :class:`~.parameter_spec.ParameterError` naming the joints the model lacks."""
    names = params.preview_joints if preview_joints is None else preview_joints
    unknown = [name for name in names if name not in joint_names]
    if unknown:
        raise ParameterError(f"preview.joints = {list(names)!r}: {', '.join(unknown)} not joints of the "
                             f"{params.model} model; its joints are {', '.join(joint_names)}")
    return PublishSettings(params.frame_prefix + params.frame_id, tuple(joint_names.index(name) for name in names),
                           params.preview_effort)


def stream_spec(params: NodeParameters, config: CraneDescription) -> StreamSpec:
    """The stream of ``params`` for the crane ``config``."""
    return StreamSpec(config=config, model=params.model, step=params.integrator_step, blend_time=params.blend_time,
                      targets=params.targets(), drive_torque=params.drive_torque, drive_duration=params.drive_duration,
                      speed_scaling=params.speed_scaling, ramp_time=params.speed_scaling_ramp_time)


def start_solver(params: NodeParameters, config: CraneDescription, stopped: Callable[[], bool]) -> SolverClient:
    """The solver of the stream of ``params``, in its own process (``solver_process``; ``stopped()`` ends the
    wait for it) or here; :class:`StartupError` if the targets have no consistent start."""
    spec, targets = stream_spec(params, config), params.targets()
    try:
        return SolverProcess(spec, stopped) if params.solver_process else LocalSolver(spec)
    except UnreachableTargetError as error:
        raise StartupError(f"ellipse.* / z.* = {targets}: {error}") from error
    except SOLVER_FAILURES as error:
        raise StartupError(f"no consistent start for the crane {params.config_file or 'packaged default'} and the "
                           f"targets {targets}: {error}") from error


def preview(params: NodeParameters) -> Preview:
    """The preview of ``params``: its horizon, its points after the sample's own, and the samples between two
    previews (at least one)."""
    return Preview(params.preview_horizon, params.preview_points - 1,
                   max(1, round(params.publish_rate / params.preview_rate)))


def refusal(parameters: list[Parameter], params: NodeParameters, server: ReferenceServer | None) -> str | None:
    """Why the change ``parameters`` of the values ``params`` is refused, or None: the table's checks, then
    with a ``server`` (else they are checked at configure) the preview's joints, a solver that stopped for a
    commanding parameter, and the reachability of targets other than those in force."""
    reason = check(parameters, SPECS)
    if reason is not None or server is None:
        return reason
    joints = next((p.value for p in parameters if p.name == "preview.joints"), None)
    try:
        if joints is not None:
            publish_settings(params, server.info.joint_names, tuple(joints))
    except ParameterError as error:
        return str(error)
    commanding = [p.name for p in parameters if p.name in COMMANDING_PARAMETERS]
    try:
        if commanding:
            server.check_computing()
    except CommandRefusedError as error:
        return f"{', '.join(commanding)}: {error} (deactivate, cleanup, configure and activate start a new solver)"
    changed = {p.name: p.value for p in parameters if p.name in TARGET_PARAMETERS}
    targets = params.changed(parameters).targets() if changed else server.stream.targets
    try:
        if targets != server.stream.targets:  # those in force are reachable
            server.check_targets(targets)
    except UnreachableTargetError as error:
        names = ", ".join(f"{name} = {value!r}" for name, value in changed.items())
        return f"{names}: target not reachable: {error}"
    return None


def apply(server: ReferenceServer, params: NodeParameters, names: list[str], accepted_ns: int) -> list[str]:
    """Send ``server`` the changes of the parameters ``names`` (their values in ``params``) accepted at
    ``accepted_ns``: one re-target for all target parameters, none if the targets are those in force.  Returns
    what was commanded, for the log.  Raises :class:`~crane_reference.stream.served.CommandRefusedError` if the
    solver stopped since the on-set check."""
    done = []
    if "command_lead" in names:
        server.set_lead(params.command_lead)
    if any(name.startswith("preview.") for name in names):
        server.preview = preview(params)
    if "speed_scaling" in names:
        k = server.command("speed_scaling", params.speed_scaling, accepted_ns=accepted_ns)
        done.append(f"speed scaling {params.speed_scaling:g} from {sample_named(server, k)}")
    targets = params.targets()
    if any(name in TARGET_PARAMETERS for name in names) and targets != server.stream.targets:
        k = server.retarget(targets, params.blend_time, accepted_ns).k  # they passed check_targets on set
        done.append(f"re-targeting to {targets} from {sample_named(server, k)} over "
                    f"{params.blend_time:g} s")
    return done
