"""Sensor rigs as data: named sensors on the ego vehicle, chosen per run (``--rig``).

One table of frozen rows, read from ``[[rig]]`` tables (the built-in ones are
``domains/rigs.toml``; a domain file may declare more, docs/catalog.md). A
sensor's pose is relative to the viewpoint's camera mount (``outputs.geometry``:
0.2 m ahead of the ego's centre, ``camera_height_m`` up), in the ego frame's
axes, so one rig fits every viewpoint. The default rig ``front`` is the
viewpoint's camera alone: runs that do not name a rig render exactly what they
rendered before rigs existed.

A rig's first camera at the mount (no offset, no rotation, the 90 degree
field of view) is the viewpoint's own camera and sees the ego's hood; the
other sensors do not (the ego's body is not modelled).
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import asdict, dataclass, field, fields
from functools import lru_cache
from importlib import resources

import numpy as np

DEFAULT_RIG = "front"
SENSOR_KINDS = ("camera", "lidar")
NAME_RE = re.compile(r"^[a-z][a-z0-9]*$")  # a sensor's folder in the episode, and the tail of its files' uid


class RigError(ValueError):
    """A rig that cannot be used; the message names the rig, the sensor and the key."""


@dataclass(frozen=True)
class Sensor:
    name: str  # lower-case letters and digits: its folder in the episode (<scenario>/e<episode>/<name>/...)
    kind: str  # camera | lidar
    x: float = 0.0  # metres forward of the viewpoint's camera mount (ego axes)
    y: float = 0.0  # metres to the left
    z: float = 0.0  # metres up
    yaw: float = 0.0  # degrees, to the left (about the ego's z)
    pitch: float = 0.0  # degrees, nose down
    roll: float = 0.0  # degrees, about the sensor's forward axis
    hfov_deg: float = 90.0  # camera: horizontal field of view
    width: int = 0  # camera: image width in pixels; 0: the run's (--width)
    height: int = 0  # camera: image height in pixels; 0: the run's (--height)
    beams: int = 64  # lidar: rows of the sweep
    fov_up_deg: float = 2.0  # lidar: elevation of the top beam
    fov_down_deg: float = -24.8  # lidar: elevation of the bottom beam
    points: int = 2048  # lidar: beams fired per revolution (azimuth steps)
    range_m: float = 120.0  # lidar: farthest return
    rate_hz: float = 10.0  # lidar: revolutions per second (recorded; a sweep is taken at one instant)

    @property
    def is_mount_camera(self) -> bool:
        """Whether this is the viewpoint's own camera (it sees the hood)."""
        return (self.kind == "camera" and self.hfov_deg == 90.0
                and (self.x, self.y, self.z, self.yaw, self.pitch, self.roll) == (0.0,) * 6)

    def size(self, width: int, height: int) -> tuple[int, int]:
        """The sensor's image size in a run at ``width`` x ``height``: its own where declared (a camera's)."""
        return self.width or width, self.height or height

    def mount_from_sensor(self) -> np.ndarray:
        """4x4: the sensor's own axes (x forward, y left, z up) to the mount's (ego axes at the mount)."""
        yaw, pitch, roll = (math.radians(a) for a in (self.yaw, self.pitch, self.roll))
        cz, sz, cy, sy, cx, sx = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
        rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])  # positive pitch turns +x down
        rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        m = np.eye(4)
        m[:3, :3] = rz @ ry @ rx
        m[:3, 3] = (self.x, self.y, self.z)
        return m


@dataclass(frozen=True)
class Rig:
    name: str
    sensors: tuple[Sensor, ...] = field(default_factory=tuple)

    @property
    def cameras(self) -> tuple[Sensor, ...]:
        return tuple(s for s in self.sensors if s.kind == "camera")

    @property
    def is_default(self) -> bool:
        """The ``front`` rig: frames written as before rigs (no sensor folder, no sensor column)."""
        return self == builtin_rigs()[DEFAULT_RIG]

    def sensor_name(self, index: int) -> str:
        """The name a frame of sensor ``index`` carries: "" for the default rig (no sensor column)."""
        return "" if self.is_default else self.sensors[index].name

    def size_of(self, sensor: str, width: int, height: int) -> tuple[int, int]:
        """The image size of the rows of ``sensor`` (a name; "": the default rig's) in a run at ``width`` x ``height``."""
        return next((s.size(width, height) for s in self.sensors if s.name == sensor), (width, height))

    def sizes(self, width: int, height: int) -> dict[str, tuple[int, int]]:
        """Every sensor's image size in a run at ``width`` x ``height``, by the name its rows carry."""
        return {self.sensor_name(i): s.size(width, height) for i, s in enumerate(self.sensors)}

    def as_json(self) -> str:
        """The rig as the episode spec and run.json carry it (workers need no file). A camera at the run's
        size is written without width and height, as rigs were before a camera could declare its own."""
        sensors = [{k: v for k, v in asdict(s).items() if not (k in _OWN_SIZE and v == 0)} for s in self.sensors]
        return json.dumps({"name": self.name, "sensors": sensors}, sort_keys=True)


_OWN_SIZE = ("width", "height")  # a camera's own image size; 0 (not written): the run's


_SENSOR_KEYS = {f.name: f for f in fields(Sensor)}
_RANGES = {"hfov_deg": (1.0, 170.0), "beams": (1, 256), "points": (8, 8192), "range_m": (1.0, 1000.0),
           "rate_hz": (0.1, 100.0), "fov_up_deg": (-89.0, 89.0), "fov_down_deg": (-89.0, 89.0),
           "width": (32, 8192), "height": (32, 8192)}  # a camera's size: as the run's (pipeline.settings)


def _sensor(entry, where: str) -> Sensor:
    if not isinstance(entry, dict):
        raise RigError(f"{where}: expected a table, got {entry!r}")
    unknown = sorted(set(entry) - set(_SENSOR_KEYS))
    if unknown:
        raise RigError(f"{where}: key {unknown[0]!r}: unknown; valid keys: {', '.join(_SENSOR_KEYS)}")
    for key in ("name", "kind"):
        if key not in entry:
            raise RigError(f"{where}: key {key!r} is missing")
    name, kind = entry["name"], entry["kind"]
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise RigError(f"{where}: key 'name': {name!r} is not lower-case letters and digits")
    where = f"{where} {name!r}"
    if kind not in SENSOR_KINDS:
        raise RigError(f"{where}: key 'kind': {kind!r} is not one of {', '.join(SENSOR_KINDS)}")
    values = {}
    for key, value in entry.items():
        if key in ("name", "kind"):
            continue
        kind_of = int if _SENSOR_KEYS[key].type in (int, "int") else float
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or (kind_of is int and not isinstance(value, int)):
            raise RigError(f"{where}: key {key!r}: expected a {'whole ' if kind_of is int else ''}number, got {value!r}")
        lo, hi = _RANGES.get(key, (-360.0, 360.0) if key in ("yaw", "pitch", "roll") else (-50.0, 50.0))
        if not lo <= value <= hi:
            raise RigError(f"{where}: key {key!r}: {value} is out of range [{lo}, {hi}]")
        values[key] = kind_of(value)
    sensor = Sensor(name=name, kind=kind, **values)
    if sensor.kind == "lidar" and (sensor.width or sensor.height):  # its faces are sized by its beams
        raise RigError(f"{where}: key {'width' if sensor.width else 'height'!r}: a camera's; a LiDAR's resolution is "
                       "its beams and points")
    if sensor.kind == "lidar" and (sensor.pitch or sensor.roll):  # its four faces turn about the ego's z only
        raise RigError(f"{where}: a LiDAR is mounted level: pitch and roll must be 0")
    if sensor.fov_down_deg >= sensor.fov_up_deg:
        raise RigError(f"{where}: key 'fov_down_deg': {sensor.fov_down_deg} must be below fov_up_deg {sensor.fov_up_deg}")
    return sensor


def rig_from_entry(entry, where: str) -> Rig:
    """A rig from one ``[[rig]]`` table (or the JSON a spec carries); RigError naming what is wrong."""
    if not isinstance(entry, dict):
        raise RigError(f"{where}: expected a table, got {entry!r}")
    name = entry.get("name")
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise RigError(f"{where}: key 'name': {name!r} is not lower-case letters and digits")
    where = f"{where} rig {name!r}"
    unknown = sorted(set(entry) - {"name", "sensor", "sensors"})
    if unknown:
        raise RigError(f"{where}: key {unknown[0]!r}: unknown; valid keys: name, sensor")
    listed = entry.get("sensor", entry.get("sensors"))
    if not isinstance(listed, list) or not listed:
        raise RigError(f"{where}: key 'sensor': give at least one sensor")
    sensors = tuple(_sensor(s, f"{where}: sensor") for s in listed)
    names = [s.name for s in sensors]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise RigError(f"{where}: sensor {twice[0]!r} is declared twice")
    if not any(s.kind == "camera" for s in sensors):
        raise RigError(f"{where}: a rig needs at least one camera")
    return Rig(name, sensors)


def rigs_from_text(text: str, source: str) -> dict[str, Rig]:
    """The ``[[rig]]`` tables of a TOML text, by name."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"{source}: {exc}") from exc
    entries = data.get("rig", [])
    if not isinstance(entries, list):
        raise RigError(f"{source}: 'rig' must be an array of tables ([[rig]])")
    rigs: dict[str, Rig] = {}
    for i, entry in enumerate(entries):
        rig = rig_from_entry(entry, f"{source}: [[rig]] {i + 1}")
        if rig.name in rigs:
            raise RigError(f"{source}: rig {rig.name!r} is declared twice")
        rigs[rig.name] = rig
    return rigs


@lru_cache(maxsize=1)
def builtin_rigs() -> dict[str, Rig]:
    return rigs_from_text(resources.files("domains").joinpath("rigs.toml").read_text(), "domains/rigs.toml")


def rig_named(name: str, declared: dict[str, Rig] | None = None) -> Rig:
    """The rig called ``name`` among the built-in ones and ``declared`` (a domain file's); or the rig
    whose JSON ``name`` is (a declared rig as run.json records it). RigError listing the valid names."""
    if name.startswith("{"):
        return rig_from_json(name)
    known = {**builtin_rigs(), **(declared or {})}
    if name not in known:
        raise RigError(f"unknown rig {name!r}; valid rigs: {', '.join(known)}")
    return known[name]


def run_rig(name: str, file_text: str | None = None, source: str = "") -> str:
    """What a run records as its rig (``PlanConfig.rig``): a built-in rig's name, or a domain file's
    declared rig as JSON (resume, verify and workers need no file)."""
    declared = rigs_from_text(file_text, source) if file_text else {}
    if name in builtin_rigs() and name not in declared:
        return name
    return rig_named(name, declared).as_json()


@lru_cache(maxsize=16)  # asked per frame and sensor; a Rig is frozen
def rig_from_json(text: str) -> Rig:
    """The rig an episode spec or run.json carries ("" is the default rig)."""
    if not text:
        return builtin_rigs()[DEFAULT_RIG]
    return rig_from_entry(json.loads(text), "the run's rig")
