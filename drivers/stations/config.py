"""The ``stations`` section of the cell config, validated at load.

Units: joint values in deg (mm for j3), velocities per second, times as named
(``_ms`` milliseconds, ``_s`` seconds). ``gear_ratio`` is *motor degrees per joint unit*
(a 50:1 reducer on a revolute joint: 50; a 10 mm/rev screw on j3: 36).
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cell.errors import ConfigError

#: the joints a cell's stations drive, in the order of every per-joint array
JOINT_NAMES = ("j1", "j2", "j3", "j4")
JointName = Literal["j1", "j2", "j3", "j4"]
_I32 = 2 ** 31 - 1


class StationConfig(BaseModel):
    """One joint station (one CANopen node)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    joint: JointName
    node_id: int = Field(ge=1, le=127)
    gear_ratio: float = Field(default=50.0, gt=0, le=100_000)       #: motor deg per joint unit
    encoder_increments: int = Field(default=10_000, ge=4, le=1 << 24)  #: per motor revolution
    limits: tuple[float, float] | None = None   #: joint units; None → the drive's whole 32-bit range
    max_velocity: float = Field(default=720.0, gt=0, le=100_000)      #: joint units/s
    quick_stop_decel: float = Field(default=5000.0, gt=0, le=1e7)     #: joint units/s²
    #: the drive applies synchronous RPDOs on SYNC (CiA 301 transmission types 1..240);
    #: a recipe may ask for ``motion.sync: sync`` only when every station can
    supports_sync: bool = True

    @model_validator(mode="after")
    def _check(self) -> "StationConfig":
        lo, hi = self.joint_limits
        if not lo < hi:
            raise ValueError(f"limits of {self.joint}: low {lo} must be below high {hi}")
        cpu = self.counts_per_unit
        if max(abs(lo), abs(hi)) * cpu >= 2 ** 31:
            raise ValueError(f"limits of {self.joint} = ({lo}, {hi}) do not fit a 32-bit position "
                             f"at {cpu:.4g} increments per unit")
        return self

    @property
    def joint_index(self) -> int:
        return JOINT_NAMES.index(self.joint)

    @property
    def joint_limits(self) -> tuple[float, float]:
        if self.limits is not None:
            return self.limits
        span = (_I32 - 1) / self.counts_per_unit
        return (-span, span)

    @property
    def counts_per_unit(self) -> float:
        """Motor increments per joint unit (encoder resolution × gear ratio / 360)."""
        return self.encoder_increments * self.gear_ratio / 360.0


class StationsConfig(BaseModel):
    """Bus, nodes and timing of the joint stations. ``stations`` is in *bus order*: the
    order set-point frames go out in, which is what seed 002's λ = σ·i counts."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    interface: str = "virtual"
    channel: str = Field(default="cell0", min_length=1)
    bitrate: int = Field(default=1_000_000, ge=10_000, le=1_000_000)
    controller_node_id: int = Field(default=127, ge=1, le=127)
    heartbeat_ms: int = Field(default=100, ge=10, le=10_000)            #: stations' producer time
    heartbeat_tolerance: float = Field(default=1.5, ge=1.1, le=10)      #: silent after × heartbeat_ms
    controller_heartbeat_ms: int = Field(default=50, ge=10, le=10_000)
    consumer_timeout_ms: int = Field(default=150, ge=20, le=60_000)     #: stations fault after this
    tpdo_event_ms: int = Field(default=10, ge=1, le=10_000)             #: actual-position period
    sdo_timeout_s: float = Field(default=0.5, gt=0, le=10)
    sdo_attempts: int = Field(default=3, ge=1, le=10)   #: an unanswered SDO request is sent this often
    boot_timeout_s: float = Field(default=2.0, gt=0, le=60)
    sync_lead_s: float = Field(default=0.01, ge=0, le=1)                #: set-points ahead of 1st SYNC
    #: each station's latency, bus order: from the end of its set-point frame on the wire to
    #: the drive applying it, s; or "measure" on the bus at start-up. Seed 002's delay λ of a
    #: station is this plus the wire time of the frames up to its own (computed per burst).
    delays_s: Literal["measure"] | tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    unknown_frames: Literal["fault", "log"] = "fault"
    stations: tuple[StationConfig, ...] = Field(default_factory=lambda: tuple(
        StationConfig(joint=j, node_id=i + 1) for i, j in enumerate(JOINT_NAMES)))

    @model_validator(mode="after")
    def _check(self) -> "StationsConfig":
        joints = [s.joint for s in self.stations]
        if sorted(joints) != list(JOINT_NAMES):
            raise ValueError(f"stations must name each of {JOINT_NAMES} exactly once, got {joints}")
        ids = [s.node_id for s in self.stations]
        if len(set(ids)) != len(ids):
            raise ValueError(f"station node ids must be unique, got {ids}")
        if self.controller_node_id in ids:
            raise ValueError(f"controller_node_id {self.controller_node_id} is also a station's node id")
        if self.consumer_timeout_ms <= self.controller_heartbeat_ms:
            raise ValueError(f"consumer_timeout_ms {self.consumer_timeout_ms} must exceed "
                             f"controller_heartbeat_ms {self.controller_heartbeat_ms}")
        if self.delays_s != "measure":
            if len(self.delays_s) != len(self.stations):
                raise ValueError(f"delays_s needs one delay per station in bus order "
                                 f"({len(self.stations)}), got {len(self.delays_s)}")
            for s, d in zip(self.stations, self.delays_s):
                if not 0 <= d < 1:
                    raise ValueError(f"delays_s for {s.joint} = {d} s must be in [0, 1)")
        return self

    def station(self, joint: str) -> StationConfig:
        return next(s for s in self.stations if s.joint == joint)

    @classmethod
    def load(cls, data, where: str = "stations") -> "StationsConfig":
        """Validate a mapping (or pass a config through).

        :raises ConfigError: naming ``where`` and every offending field.
        """
        if isinstance(data, cls):
            return data
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            from cell.yamlio import error_text
            fields = "; ".join(f"{where}.{'.'.join(map(str, e['loc'])) or '(section)'}: {error_text(e, cls)}"
                               for e in exc.errors())
            raise ConfigError(f"invalid joint-station config: {fields}") from None
