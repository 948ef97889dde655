"""Any MuJoCo model as a robot: its actuators, joints, sensors, bodies and sites by name.

``MjcfRobot(model="acrobot.xml")`` loads the file with dm_control's ``mjcf`` parser,
which follows ``<include>`` files and the ``<compiler>`` asset folders (meshes,
textures), and keeps the model's ``<option>`` (timestep, integrator, gravity): the
model is its own world, no arena around it. A file MuJoCo cannot compile is refused
with MuJoCo's own message and the file; a name the model lacks, with the close
matches and the names it has.

``control`` changes how actuators are driven (``elbow: {mode: position, gain: 20}``):
``motor`` (the command is the force or torque, times ``gain``), ``position`` (a
servo to the commanded joint position, stiffness ``gain``) or ``velocity`` (a
servo to the commanded joint velocity, damping ``gain``); actuators it leaves out
stay as the model says.

``joints`` changes a joint's passive properties (``hinge: {damping: 0.03}``): damping (N m s/rad
or N s/m), frictionloss (N m or N), armature (kg m^2 or kg) and stiffness (N m/rad or N/m), as
dm_control's tasks change their models (finger spin lowers the spinner's damping).

A task reads the robot through :class:`Reader` objects it asks for by source and
name (``reader("joint_pos", "shoulder")``, ``reader("site_pos", "tip")``); the
robot resolves them in the compiled model when it is bound. Joint positions and
velocities are exact; body and site quantities come from frame sensors the robot
adds to its model, which MuJoCo computes at the start of the last physics step of
an env step (one ``timestep`` old, see :mod:`robots.physics`).
"""

from __future__ import annotations

import difflib
import functools
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from dm_control import mjcf

from params import ConfigError, finite, require
from params.declare import REQUIRED, check_fields, param
from robots.folders import MODEL_FOLDERS
from robots.base import Robot
from robots.binding import JointHandle, actuator_id, sensor_slice
from robots.physics import BatchedPhysics

CONTROL_MODES = ("motor", "position", "velocity")
JOINT_PROPERTIES = ("damping", "frictionloss", "armature", "stiffness")
#: A body or site quantity -> (MuJoCo frame sensor, entries).
FRAME_SENSORS = {"pos": ("framepos", 3), "quat": ("framequat", 4), "vel": ("framelinvel", 3),
                 "angvel": ("frameangvel", 3), "zaxis": ("framezaxis", 3)}
#: Every source a task can read, with what it names.
SOURCES = {"joint_pos": "joint", "joint_vel": "joint", "sensor": "sensor",
           **{f"{obj}_{q}": obj for obj in ("body", "site", "geom") for q in FRAME_SENSORS}}
_KINDS = {"actuator": "actuator", "joint": "joint", "sensor": "sensor", "body": "body",
          "site": "site", "geom": "geom"}
FRAMES = ("site", "geom", "body")  # what a frame name may be, searched in this order
_ONE_DOF = ("hinge", "slide")
_PROBE = "probe:"  # names of the frame sensors the robot adds for its readers


def missing_name(kind: str, name: str, names: list[str], where: str) -> ConfigError:
    """``"<where>: the model has no <kind> '<name>'; close: ...; its <kind>s: ..."``."""
    close = difflib.get_close_matches(name, names, n=3, cutoff=0.5)
    hint = f"close matches: {', '.join(close)}; " if close else ""
    plural = "bodies" if kind == "body" else f"{kind}s"
    return ConfigError(f"{where}: the model has no {kind} {name!r}; {hint}"
                       f"its {plural}: {', '.join(names) or 'none'}")




def find_model(path: str) -> Path:
    """``path`` as given if it names a file, else the first of :data:`MODEL_FOLDERS` holding it."""
    file = Path(path).expanduser()
    if file.is_absolute() or file.is_file():
        return file
    return next((d / file for d in MODEL_FOLDERS if (d / file).is_file()), file)


def load_model(path: str) -> mjcf.RootElement:
    """The MJCF model at ``path``, checked to compile; a missing file or one MuJoCo refuses is
    one line (MuJoCo's own message and the file)."""
    file = find_model(path)
    require(file.is_file(), "robot.model must be an MJCF file that exists", str(file))
    try:
        mujoco.MjModel.from_xml_path(str(file))
    except ValueError as err:
        message = " ".join(str(err).split())
        raise ConfigError(f"robot.model {file}: MuJoCo cannot compile it: {message}") from None
    try:
        return mjcf.from_path(str(file))
    except Exception as err:  # noqa: BLE001 - dm_control's parser: any refusal is one line
        message = " ".join(str(err).split())
        raise ConfigError(f"robot.model {file}: dm_control cannot read it: {message}") from None


@functools.lru_cache(maxsize=16)
def _compile(xml: str, assets: tuple[tuple[str, bytes], ...]) -> mujoco.MjModel:
    """``xml`` compiled with its ``assets``, once per process for the same text: the ranges of a
    task's robot are read from it, and a model with dm_control's generated textures takes
    ~0.3 s to compile (the pendulum, the finger) where its text takes ~0.05 s to write."""
    return mujoco.MjModel.from_xml_string(xml, assets=dict(assets))


@dataclass
class Reader:
    """One named quantity of the robot, ``size`` numbers per copy; usable once bound."""

    source: str
    name: str
    size: int
    element: object
    read_slice: slice | None = None
    joint: JointHandle | None = None

    def read(self, physics: BatchedPhysics) -> np.ndarray:
        """``(num_envs, size)``."""
        if self.source == "joint_pos":
            return self.joint.pos(physics)[:, None]
        if self.source == "joint_vel":
            return self.joint.vel(physics)[:, None]
        return physics.sensordata[:, self.read_slice]


@dataclass(eq=False)
class MjcfRobot(Robot):
    """A robot made from any MJCF file; tasks read and command it by name."""

    model: str = param(REQUIRED, "the MJCF file (a relative path: from the config folder)")
    control: dict | None = param(None, "actuator name: {mode: motor, position or velocity, gain: "
                                       "number} (null: every actuator as the model says)")
    joints: dict | None = param(None, "joint name: {damping, frictionloss, armature, stiffness: "
                                      "number >= 0} set on the model (null: as the model says)")
    _readers: list = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        check_fields(self, "robot")
        self.mjcf_model = load_model(self.model)
        self.timestep = float(self.mjcf_model.option.timestep or 0.002)  # MuJoCo's default
        for name, spec in (self.control or {}).items():
            self._set_control(name, spec)
        for name, spec in (self.joints or {}).items():
            self._set_joint(name, spec)
        self._actuator_ids: np.ndarray | None = None

    # -- names ---------------------------------------------------------------------
    def names(self, kind: str) -> list[str]:
        """The names the model gives its ``kind`` elements (actuator, joint, sensor, body, site)."""
        return [e.name for e in self.mjcf_model.find_all(_KINDS[kind])
                if e.name and not e.name.startswith(_PROBE)]

    def frame(self, name: str, where: str) -> tuple[str, object]:
        """``(kind, element)`` of a frame: ``site:tip``, ``geom:target``, ``body:torso``, or a
        bare name that one kind of :data:`FRAMES` has (a name two kinds share needs its kind)."""
        kind, _, bare = str(name).rpartition(":")
        if kind:
            require(kind in FRAMES, f"{where}: a frame is site:, geom: or body: and a name", name)
            return kind, self.element(kind, bare, where)
        found = [k for k in FRAMES if self.mjcf_model.find(_KINDS[k], bare) is not None]
        require(len(found) < 2, f"{where}: {bare!r} names a {' and a '.join(found)}; say which "
                f"({', '.join(f'{k}:{bare}' for k in found)})", name)
        if not found:
            everything = [n for k in FRAMES for n in self.names(k)]
            raise missing_name("frame (site, geom or body)", bare, everything, where)
        return found[0], self.element(found[0], bare, where)

    def element(self, kind: str, name: str, where: str):
        """The model's ``kind`` element called ``name``; else one line naming ``where`` it was
        asked for, the close matches and the names the model has."""
        found = self.mjcf_model.find(_KINDS[kind], str(name))
        if found is None:
            raise missing_name(kind, str(name), self.names(kind), where)
        return found

    def actuators(self) -> list[str]:
        """Every actuator, in the model's order, by its name; an unnamed one by the joint it
        drives (Gymnasium's models leave their motors unnamed), else ``actuator_<i>``."""
        labels = []
        for i, actuator in enumerate(self.mjcf_model.find_all("actuator")):
            joint = getattr(actuator, "joint", None)
            labels.append(actuator.name or getattr(joint, "name", None) or f"actuator_{i}")
        return labels

    def actuator_column(self, name: str, where: str) -> int:
        """The index in :meth:`actuators` of the actuator ``name`` (its name, or its joint's)."""
        order = self.actuators()
        if str(name) not in order:
            raise missing_name("actuator", str(name), order, where)
        return order.index(str(name))

    def joint_ranges(self) -> dict[str, tuple[float, float]]:
        """The position range of each limited hinge and slide joint, by name (unlimited ones
        are left out), as the compiled model has it."""
        model = self._compiled()
        found = {}
        for name in self.hinges_and_slides():
            index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, self.element("joint", name, "").full_identifier)
            if index >= 0 and model.jnt_limited[index]:
                found[name] = (float(model.jnt_range[index, 0]), float(model.jnt_range[index, 1]))
        return found

    def _compiled(self) -> mujoco.MjModel:
        """The model as it stands, compiled (read only: its ranges)."""
        return _compile(self.mjcf_model.to_xml_string(), tuple(sorted(self.mjcf_model.get_assets().items())))

    def control_ranges(self) -> dict[str, tuple[float, float]]:
        """The ``[low, high]`` command range of each actuator the model limits, by its name in
        :meth:`actuators` (after its defaults classes and a control mode's change; actuators the
        model leaves unlimited are left out), from one compilation of the model."""
        model = self._compiled()
        return {name: (float(model.actuator_ctrlrange[i, 0]), float(model.actuator_ctrlrange[i, 1]))
                for i, name in enumerate(self.actuators())
                if model.actuator_ctrllimited[i] and model.actuator_ctrlrange[i, 0] < model.actuator_ctrlrange[i, 1]}

    # -- control modes -------------------------------------------------------------
    def _set_control(self, name: str, spec) -> None:
        """Replaces actuator ``name`` with one of ``spec``'s mode and gain, on the same joint and
        with the same control and force ranges."""
        where = f"robot.control.{name}"
        old = self.mjcf_model.find_all("actuator")[self.actuator_column(name, where)]
        require(isinstance(spec, dict) and set(spec) <= {"mode", "gain"} and spec.get("mode")
                in CONTROL_MODES, f"{where} must be {{mode: {' | '.join(CONTROL_MODES)}, gain: "
                f"number}}", spec)
        gain = float(spec.get("gain", 1.0))
        require(gain > 0, f"{where}.gain must be a finite number > 0", gain)
        require(old.joint is not None, f"{where}: only an actuator on a joint can change mode",
                name)
        keep = {k: getattr(old, k) for k in ("ctrlrange", "forcerange", "ctrllimited",
                                             "forcelimited") if getattr(old, k) is not None}
        joint = old.joint
        old.remove()
        gains = {"motor": {"gear": [gain]}, "position": {"kp": gain}, "velocity": {"kv": gain}}
        self.mjcf_model.actuator.add(spec["mode"], name=name, joint=joint,
                                     **gains[spec["mode"]], **keep)

    def _set_joint(self, name: str, spec) -> None:
        """Sets joint ``name``'s passive properties to ``spec``'s values."""
        where = f"robot.joints.{name}"
        joint = self.element("joint", name, where)
        require(isinstance(spec, dict) and spec and set(spec) <= set(JOINT_PROPERTIES),
                f"{where} must be {{{', '.join(JOINT_PROPERTIES)}: number}}", spec)
        for key, value in spec.items():
            require(finite(value) and value >= 0,
                    f"{where}.{key} must be a finite number >= 0", value)
            setattr(joint, key, float(value))

    # -- readers and commands ------------------------------------------------------
    def frame_reader(self, quantity: str, name: str, where: str) -> Reader:
        """A frame sensor's :class:`Reader` of ``quantity`` (pos, quat, vel, angvel, zaxis) of
        the frame ``name`` (see :meth:`frame`)."""
        kind, element = self.frame(name, where)
        return self.reader(f"{kind}_{quantity}", element.name, where)

    def reader(self, source: str, name: str, where: str) -> Reader:
        """A :class:`Reader` of ``source`` (a key of :data:`SOURCES`) for the element ``name``;
        a frame sensor is added to the model for a body or site quantity (before compiling)."""
        require(source in SOURCES, f"{where} must read one of {', '.join(SOURCES)}", source)
        kind = SOURCES[source]
        element = self.element(kind, name, where)
        if kind == "joint":
            require(element.type in (None, *_ONE_DOF), f"{where}: joint {name!r} is a "
                    f"{element.type} joint; joint_pos and joint_vel read hinge and slide joints "
                    f"(read its body with body_pos, body_quat, ...)", name)
            reader = Reader(source, str(name), 1, element)
        elif kind == "sensor":
            reader = Reader(source, str(name), self.sensor_size(str(name)), element)
        else:
            reader = self._frame_reader(source, kind, element)
        self._readers.append(reader)
        return reader

    def _frame_reader(self, source: str, kind: str, element) -> Reader:
        sensor_type, size = FRAME_SENSORS[source.split("_", 1)[1]]
        sensor = self.mjcf_model.sensor.add(sensor_type, name=f"{_PROBE}{source}:"
                                            f"{element.name}:{len(self._readers)}", objtype=kind,
                                            objname=element)
        return Reader(source, str(element.name), size, sensor)

    def sensor_size(self, name: str) -> int:
        """How many numbers the model's sensor ``name`` gives (in the model compiled as it stands)."""
        model = self._compiled()
        return int(model.sensor_dim[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)])

    def bind(self, physics: BatchedPhysics) -> None:
        """Resolves every reader and the actuators in the compiled model."""
        model = physics.model
        for reader in self._readers:
            if reader.source in ("joint_pos", "joint_vel"):
                reader.joint = JointHandle.of(model, reader.element)
            else:
                reader.read_slice = sensor_slice(model, reader.element)
                reader.size = reader.read_slice.stop - reader.read_slice.start
        self._actuator_ids = np.asarray([actuator_id(model, a) for a in
                                         self.mjcf_model.find_all("actuator")], dtype=np.int64)

    def command(self, physics: BatchedPhysics, columns: np.ndarray, values: np.ndarray) -> None:
        """Sets the actuators at ``columns`` (indices into :meth:`actuators`) of every copy to
        ``values`` (``(num_envs, len(columns))``)."""
        physics.ctrl[:, self._actuator_ids[columns]] = values

    def set_joint(self, physics: BatchedPhysics, joint: Reader, mask: np.ndarray, pos, vel) -> None:
        """Places the ``mask`` copies' joint (a ``joint_pos`` reader) at ``pos`` moving at ``vel``."""
        joint.joint.set(physics, mask, pos, vel)

    def hinges_and_slides(self) -> list[str]:
        """The names of the model's 1-dof joints (hinge and slide), in its order."""
        return [j.name for j in self.mjcf_model.find_all("joint")
                if j.name and j.type in (None, *_ONE_DOF)]
