"""The cell config (``deploy/cell.yaml``): one section per subsystem, validated at load.

Each section is a pydantic model with ``extra="forbid"``: an unknown key or
a value out of range is a :class:`~cell.errors.ConfigError` naming file, line and field.
Driver sections reuse the drivers' own models (``plc`` → ``drivers.plc.PlcConfig``,
``stations`` → ``drivers.stations.StationsConfig``); ``camera`` is handed to the camera
registry (``drivers.camera.from_config``), which rejects unknown backends and options.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from cell import paths
from cell.errors import CellError
from cell.kinematics import Scara
from cell.opcua.config import OpcuaSection
from cell.robots import PRESETS, Geometry
from cell.yamlio import load_model
from drivers.plc import PlcConfig
from drivers.stations import StationsConfig

FORMAT = "cell-config/1"


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RobotSection(_Section):
    preset: str | None = "seed000"
    geometry: Geometry | None = None
    elbow: Literal["right", "left"] = "right"

    @model_validator(mode="after")
    def _one(self) -> "RobotSection":
        if (self.preset is None) == (self.geometry is None):
            raise ValueError("give exactly one of robot.preset and robot.geometry")
        if self.preset is not None and self.preset not in PRESETS:
            raise ValueError(f"unknown robot preset {self.preset!r}; known: {sorted(PRESETS)}")
        return self

    def scara(self) -> Scara:
        return Scara(self.geometry) if self.geometry else Scara.preset(self.preset)


class VisionSection(_Section):
    calibration: str = "var/calibration.json"      #: PlaneCalibration JSON (cell-vision-calibration/1)
    tool_radius_mm: float = Field(default=3.0, gt=0.2, le=20)
    radius_tolerance: float = Field(default=0.3, gt=0, lt=1)
    grab_timeout_s: float = Field(default=2.0, gt=0, le=60)   #: a grab that takes longer is fault 301
    #: a tool search looks this far (mm) around where the model puts the tool, then the whole frame
    window_mm: float = Field(default=5.0, gt=0, le=100)


class RecipesSection(_Section):
    directory: str = "recipes"
    max_bytes: int = Field(default=64 * 1024, ge=1024, le=16 * 1024 * 1024)   #: larger files are refused unread
    settle_s: float = Field(default=1.0, ge=0, le=60)   #: a changed file must stay unchanged this long
    #: activate recipes marked ``production: false`` (shipped examples); off on a production cell
    allow_examples: bool = False


class LogSection(_Section):
    path: str = "var/cell.sqlite"
    retention_days: int = Field(default=365, ge=1, le=36500)
    format: Literal["json", "console"] = "json"
    level: str = "INFO"


class ControllerSection(_Section):
    scan_s: float = Field(default=0.01, gt=0, le=1)
    recipe_refresh_s: float = Field(default=1.0, gt=0, le=3600)


class CycleSection(_Section):
    move_timeout_s: float = Field(default=10.0, gt=0, le=600)
    reach_tol_deg: float = Field(default=0.001, gt=0, le=1)
    tool_phi_deg: float = Field(default=0.0, ge=-360, le=360)


class SchedulerSection(_Section):
    health_interval_s: float = Field(default=10.0, gt=0, le=3600)
    drift_interval_s: float = Field(default=30.0, gt=0, le=86400)
    drift_window: int = Field(default=20, ge=2, le=10000)
    drift_threshold_mm: float = Field(default=0.5, gt=0, le=100)
    retention_interval_s: float = Field(default=3600.0, gt=0, le=7 * 86400)


class CalibrationSection(_Section):
    """Robot calibration from the hand camera (seed 004 per joint, seed 001 over a board).

    ``file``: the kinematic calibration the cell loads at start and ``cellctl calibrate
    kinematics`` writes (absent: the nominal model; corrupt or another robot's: the start
    is refused). ``hand_camera``: the hand camera's driver config (as ``camera``; real
    hardware only); ``hand_calibration``: its plane calibration, origin on the tool axis
    (``cellctl calibrate-camera`` with the board centred under the tool).
    ``board``: the board of known points (``cellctl calibrate-camera`` board format; default
    :data:`cell.vision.calibration.DEFAULT_BOARD`, 100 mm pitch, so one point is in view at a time).
    ``z_mm``: d3 held while calibrating. ``runs``: seed 004 runs per joint. ``poses`` /
    ``holdout``: poses the kinematic fit uses / keeps back for the held-out check, which
    must cut the held-out error by ``min_gain`` (relative) for the result to be written.
    ``anchors``: poses where the cell's fixed camera measures the tool in the base frame,
    which separate the board's rotation from θ1's zero (0: the board alone; then they
    merge). ``radius_sigma_mm``: how well the nominal links give the target's distance from a
    joint's axis (the radius prior of seed 004's circle fit on a short arc).
    """

    file: str = "var/robot-calibration.json"
    hand_camera: dict[str, Any] | None = None
    hand_calibration: str = "var/hand-camera.json"
    target_radius_mm: float = Field(default=3.0, gt=0.2, le=20)
    board: dict[str, Any] | None = None
    z_mm: float = 0.0
    runs: int = Field(default=3, ge=1, le=50)
    poses: int = Field(default=24, ge=4, le=500)
    holdout: int = Field(default=12, ge=3, le=500)
    anchors: int = Field(default=6, ge=0, le=9)   #: poses where the cell camera sees the tool (0: board only)
    min_gain: float = Field(default=0.1, ge=0, lt=1)
    radius_sigma_mm: float = Field(default=2.0, gt=0, le=50)   #: how well l1 + l2 are known (seed 004's radius prior)

    @model_validator(mode="after")
    def _board(self) -> "CalibrationSection":
        self.circle_board()
        return self

    def circle_board(self):
        """``board`` as a :class:`~cell.vision.calibration.CircleGridBoard` (None if not
        given). Raises ValueError unless it is a valid circle grid: its points are what the
        hand camera measures."""
        if self.board is None:
            return None
        from cell.vision.calibration import board_from_dict
        if self.board.get("kind") != "circles":
            raise ValueError(f"calibration.board must be a circle grid (kind: circles, not "
                             f"{self.board.get('kind')!r}): its points are what the hand camera measures")
        try:
            return board_from_dict(dict(self.board))
        except (CellError, TypeError, ValueError) as exc:
            if hasattr(exc, "loc"):               # a field of the board: point at its line
                err = ValueError(exc.detail)
                err.loc = ("board", *exc.loc)
                raise err from None
            raise ValueError(f"calibration.board: {exc}") from None


class PlantSection(_Section):
    """The plant path (``cell/plant.md``): the cycle log's records to an MQTT broker for the
    historian (:mod:`cell.plant.outbox`). Absent (the default): the cell needs no broker.

    ``host``/``port``: the broker. ``site``, ``line`` and ``cell`` name the cell's topics
    ``<site>/<line>/<cell>/...`` (``cell`` defaults to the config's ``name``). ``window``:
    records sent beyond the historian's watermark at most; ``resend_s``: how long the
    watermark may stand still with records out before they are sent again.

    Security (the broker of ``deploy/mosquitto/``): ``tls`` connects over TLS, checking the
    broker's certificate against ``ca_file`` (PEM; absent: the system's CAs); with
    ``password_file`` (a file holding the password alone, readable by the controller's
    user only) the cell logs in as ``username``, by default its cell id
    ``site/line/cell``, the name the broker's ACL gives its topics to. Relative paths are
    taken from the config file's folder; the password is read when the outbox starts.
    """

    host: str = Field(min_length=1)
    port: int = Field(default=1883, ge=1, le=65535)
    site: str
    line: str
    cell: str | None = None
    keepalive_s: int = Field(default=10, ge=2, le=600)
    window: int = Field(default=500, ge=1, le=100000)
    resend_s: float = Field(default=30.0, gt=0, le=3600)
    tls: bool = False
    ca_file: str | None = None
    username: str | None = Field(default=None, min_length=1)
    password_file: str | None = None

    @model_validator(mode="after")
    def _names(self) -> "PlantSection":
        from cell.plant.topics import TopicError, check_segment
        try:
            for what in ("site", "line", "cell"):
                if getattr(self, what) is not None:
                    check_segment(f"plant.{what}", getattr(self, what))
        except TopicError as exc:
            raise ValueError(str(exc)) from None
        if self.username is not None and self.password_file is None:
            raise ValueError("plant.username needs plant.password_file (the password, in a file of its own)")
        if self.ca_file is not None and not self.tls:
            raise ValueError("plant.ca_file is only used with plant.tls: true")
        return self

    def outbox_settings(self, cell_name: str):
        """The :class:`~cell.plant.outbox.OutboxSettings` for a cell named ``cell_name``;
        raises ConfigError if the password file cannot be read or is empty."""
        from cell.plant.mqtt import Security, read_password
        from cell.plant.outbox import OutboxSettings
        from cell.plant.topics import CellTopics
        topics = CellTopics(self.site, self.line, self.cell or cell_name)
        security = None
        if self.tls or self.password_file is not None:
            password = (None if self.password_file is None
                        else read_password(self.password_file, "plant.password_file"))
            security = Security(tls=self.tls, ca_file=self.ca_file,
                                username=(self.username or topics.path) if password is not None else None,
                                password=password)
        return OutboxSettings(host=self.host, port=self.port, topics=topics, keepalive_s=self.keepalive_s,
                              window=self.window, resend_s=self.resend_s, security=security)


class SimSection(_Section):
    """Only for ``--sim``: the plant that stands in for the real robot and camera."""
    plant: str = "deploy/plants/default.yaml"
    part_jitter_mm: float = Field(default=1.0, ge=0, le=20)
    station_sigma_s: float = Field(default=0.0005, ge=0, le=0.1)   #: seed 002 λ = σ·i
    camera_px: tuple[int, int] = (640, 512)                          #: rendered image size
    camera_mm_per_px: float = Field(default=0.08, gt=0.001, le=1)    #: 51 × 41 mm field
    seed: int = 0


class CellConfig(_Section):
    format: Literal["cell-config/1"] = FORMAT
    name: str = "cell-1"
    robot: RobotSection = RobotSection()
    plc: PlcConfig = PlcConfig()
    stations: StationsConfig = StationsConfig()
    camera: dict[str, Any] = Field(default_factory=lambda: {"backend": "opencv", "source": 0})
    vision: VisionSection = VisionSection()
    recipes: RecipesSection = RecipesSection()
    log: LogSection = LogSection()
    controller: ControllerSection = ControllerSection()
    cycle: CycleSection = CycleSection()
    scheduler: SchedulerSection = SchedulerSection()
    calibration: CalibrationSection = CalibrationSection()
    plant: PlantSection | None = None           #: None: no plant path, no broker needed
    #: the read-only OPC UA server for the MES (cell/opcua/); absent: none
    opcua: OpcuaSection | None = None
    sim: SimSection | None = None

    @classmethod
    def load(cls, path: Path | str) -> "CellConfig":
        """Load and validate ``path``; raises ConfigError naming file, line and field.
        Relative paths written in the file (certificates, recipes, log, calibrations, plant,
        a replay camera's folder) are taken from the file's folder; the defaults of keys it
        leaves out, from the project's (:mod:`cell.paths`), never from the shell's."""
        cfg = load_model(path, cls, "cell config")
        tls = cfg.plc.tls.resolved(Path(path).resolve().parent)
        cfg = cfg.model_copy(update={"plc": cfg.plc.model_copy(update={"tls": tls})})
        return cfg.with_paths(path)

    def with_paths(self, file: Path | str | None = None) -> "CellConfig":
        """This config with every relative file path made absolute: a value written in the
        config ``file`` against that file's folder, a default (every value when ``file`` is
        None: a config built in code) against the project's folder."""
        def fix(section: BaseModel, *names: str) -> BaseModel:
            update = {}
            for name in names:
                value = getattr(section, name)
                if not value or Path(value).is_absolute():
                    continue
                written = file is not None and name in section.model_fields_set
                update[name] = str(paths.from_file(value, file) if written else paths.project(value))
            return section.model_copy(update=update) if update else section

        def camera(conf: dict[str, Any] | None, written: bool) -> dict[str, Any] | None:
            # the replay camera reads a folder of images (drivers.camera: backend folder)
            if not conf or conf.get("backend") != "folder" or not isinstance(conf.get("path"), str) \
                    or Path(conf["path"]).is_absolute():
                return conf
            base = paths.from_file(conf["path"], file) if written and file is not None \
                else paths.project(conf["path"])
            return {**conf, "path": str(base)}

        cal = fix(self.calibration, "file", "hand_calibration")
        cal = cal.model_copy(update={"hand_camera": camera(cal.hand_camera, "hand_camera" in cal.model_fields_set)})
        update: dict[str, Any] = {
            "vision": fix(self.vision, "calibration"),
            "recipes": fix(self.recipes, "directory"),
            "log": fix(self.log, "path"),
            "calibration": cal,
            "camera": camera(self.camera, "camera" in self.model_fields_set),
        }
        if self.sim is not None:
            update["sim"] = fix(self.sim, "plant")
        if self.opcua is not None:
            update["opcua"] = fix(self.opcua, "pki")
        if self.plant is not None:
            update["plant"] = fix(self.plant, "ca_file", "password_file")
        return self.model_copy(update=update)
