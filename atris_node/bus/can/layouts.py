"""The frame table: every message layout of the CAN database, written once.

:mod:`atris_node.bus.can.dbc` turns these layouts into cantools messages: the unit frames
once per unit (16 identical blocks), the negotiation frames once per identifier they use.
The byte layouts of the negotiation frames are those of
:mod:`atris_node.bus.negotiation.frames`; a test holds the two equal.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from atris_node.bus.can.ids import FrameKind
from atris_node.bus.negotiation.frames import FrameKind as NegotiationKind

DISTANCE_CHOICES = {65533: "no_sector", 65534: "no_return", 65535: "invalid"}
E2E_CRC = "CRC"
E2E_COUNTER = "Counter"
CRC_COMMENT = "E2E Profile 1 CRC-8 SAE J1850 over data ID and bytes 1..7"


@dataclass(frozen=True)
class SignalSpec:
    """One little-endian signal: bit ``start``, ``length`` bits, physical = raw * scale +
    offset within ``minimum..maximum``; ``choices`` name reserved raw values; ``role`` is
    its E2E role (``CRC``, ``Counter``) or empty."""

    name: str
    start: int
    length: int
    minimum: float
    maximum: float
    comment: str
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    signed: bool = False
    choices: dict[int, str] = field(default_factory=dict)
    role: str = ""


@dataclass(frozen=True)
class MessageSpec:
    """A message layout: name suffix, comment, signals; ``e2e`` when protected."""

    suffix: str
    comment: str
    signals: tuple[SignalSpec, ...]
    e2e: bool = False


S = SignalSpec
E2E_HEADER = (
    S(E2E_CRC, 0, 8, 0, 255, CRC_COMMENT, role=E2E_CRC),
    S(E2E_COUNTER, 8, 4, 0, 14, "E2E alive counter 0..14", role=E2E_COUNTER),
)
FAULTS = (
    ("CameraLost", "camera stopped delivering sub-frames"),
    ("LaserFault", "projector fault"),
    ("BusError", "error frames, failed sends or bus-off since the last cycle"),
    ("DeadlineMiss", "a cycle was sent later than period + tolerance"),
    ("PlanConflict", "code plan conflict"),
    ("ForeignCode", "sustained interference on the own code"),
    ("LowSignal", "laser energy at the level of the uncompensated remainder"),
    ("Calibration", "calibration missing or does not fit"),
)
STATES = {0: "INIT", 1: "NEGOTIATING", 2: "RUNNING", 3: "NO_CODE", 4: "FAULT", 5: "STOPPED"}


#: what a sector distance's reserved values mean
_STATES_TEXT = ("; no_return: no obstacle met by any light sheet within the range "
                "(z_max); invalid: not known")


def _distance(name: str, start: int, comment: str) -> SignalSpec:
    return S(name, start, 16, 0, 65.532, comment, scale=0.001, unit="m",
             choices=DISTANCE_CHOICES)


def _percent(name: str, start: int, comment: str) -> SignalSpec:
    return S(name, start, 8, 0, 100, comment, scale=0.5, unit="%")


STATUS = MessageSpec("Status", "cycle status: state, code, faults, data age", (*E2E_HEADER,
    S("State", 12, 4, 0, 15, "unit state", choices=STATES),
    *(S(f"Fault_{name}", 16 + i, 1, 0, 1, text) for i, (name, text) in enumerate(FAULTS)),
    S("CodeRow", 24, 8, 0, 255, "1-based Walsh row of the code in use, 0 = none"),
    S("CodeLength", 32, 8, 0, 255, "code length N, sub-frames per period"),
    S("ChipRate", 40, 16, 0, 6553.5, "chip (sub-frame) rate", scale=0.1, unit="Hz"),
    S("DataAge", 56, 8, 0, 2.54, "age of the newest sub-frame used at send time; "
      "255 = no data", scale=0.01, unit="s", choices={255: "no_data"}),
), e2e=True)
QUALITY = MessageSpec("Quality", "cycle status: measurement counter and signal quality",
                      (*E2E_HEADER,
    S("SectorCount", 12, 4, 1, 16, "number of sectors the unit publishes", offset=1),
    S("MeasurementCounter", 16, 16, 0, 65535, "counter of the measurement, modulo 65536"),
    _percent("AmbientLevel", 32, "mean raw level of the sub-frames, of full scale"),
    _percent("SaturatedFraction", 40, "saturated pixels, of all pixels"),
    S("ForeignCodeEnergy", 48, 8, 0, 255, "energy of other codes, of the own line energy; "
      "255 = 255 % or more", unit="%"),
    S("DroppedSubFrames", 56, 8, 0, 255, "sub-frames lost; 255 = 255 or more"),
), e2e=True)
NEAREST = MessageSpec("Nearest", "nearest obstacle over all sectors", (*E2E_HEADER,
    S("Valid", 12, 1, 0, 1, "1 = Distance and Bearing hold a measured obstacle"),
    _distance("Distance", 16, "horizontal range of the nearest obstacle"),
    S("Bearing", 32, 16, -180, 180, "bearing, 0 ahead, positive left (ISO 8855)",
      scale=0.01, unit="deg", signed=True, choices={-32768: "not_available"}),
    S("ClosingSpeed", 48, 8, -25.4, 25.4, "rate of approach, positive = closing",
      scale=0.2, unit="m/s", signed=True, choices={-128: "not_available"}),
    S("TimeToCollision", 56, 8, 0, 25.4, "time to collision at the current closing speed",
      scale=0.1, unit="s", choices={255: "not_available"}),
), e2e=True)
SECTORS = MessageSpec("Sectors", "two sector distances per frame; frames for sectors 0-1, "
                      "2-3, ... back to back each cycle", (*E2E_HEADER,
    S("SectorIndex", 12, 4, 0, 15, "index of the first sector in this frame (even); "
      "0 = right edge"),
    _distance("Distance0", 16, "horizontal range in sector SectorIndex" + _STATES_TEXT),
    _percent("Confidence0", 32, "confidence of Distance0"),
    _distance("Distance1", 40, "horizontal range in sector SectorIndex + 1" + _STATES_TEXT),
    _percent("Confidence1", 56, "confidence of Distance1"),
), e2e=True)
#: the unit frames, by their offset in the unit's ID block
UNIT_MESSAGES = {FrameKind.STATUS: STATUS, FrameKind.QUALITY: QUALITY,
                 FrameKind.NEAREST: NEAREST, FrameKind.SECTORS: SECTORS}

NAME_SIGNAL = (S("Name", 0, 64, 0, 2**64 - 1, "64-bit NAME of the sender; the lowest NAME "
                 "wins"),)
REQUEST = MessageSpec("Request", "Code negotiation (docs/negotiation.md): request for claims, "
                      "every unit re-announces its PLAN and CLAIM", NAME_SIGNAL)
CLAIM = MessageSpec("Claim", "Code negotiation: claim of a Walsh row (1-based), strobed after "
                    "250 ms without a lower-NAME claim of it", NAME_SIGNAL)
CANNOT_CLAIM = MessageSpec("CannotClaim", "Code negotiation: the sender has no code and keeps "
                           "its laser off", NAME_SIGNAL)
PLAN = MessageSpec("Plan", "Code negotiation: the plan the sender uses (the lowest NAME's "
                   "wins), or with Flag_Proposal asks for", (
    S("CodeLength", 0, 8, 2, 128, "code length N, a power of two"),
    S("Mode", 8, 8, 0, 1, "code set: async (log2 N cyclic orthogonal rows) or sync (N - 1 "
      "rows, sub-frames aligned to SYNC)"),
    S("Flag_Proposal", 16, 1, 0, 1, "a request for this plan, addressed to the lowest NAME"),
    S("Flag_Conflict", 17, 1, 0, 1, "the sender cannot adopt the plan of the lowest NAME"),
    S("Flag_Established", 18, 1, 0, 1, "the sender owns a code under this plan; a joining "
      "unit adopts it"),
    S("Flag_Grown", 19, 1, 0, 1, "the leader grew N to fit the units; whoever leads goes "
      "back to the smallest N that fits once they are gone"),
    S("Nonce", 24, 8, 0, 255, "random per start of the sender; tells its own echo from a "
      "unit with the same identity"),
    S("ChipRate", 32, 32, 0, 4294967.295, "chip (sub-frame) rate in millihertz steps",
      scale=0.001, unit="Hz"),
))
SYNC = MessageSpec("Sync", "Code negotiation, sync mode: the lowest NAME's code period "
                   "starts; the others align their sub-frames to it", (
    S("Counter", 0, 16, 0, 65535, "code periods since the leader started, modulo 65536"),
    S("CodeLength", 16, 8, 2, 128, "code length N of the leader's plan"),
    S("CodePeriod", 32, 32, 0, 4294967295, "duration of one code period (N chips)",
      unit="us"),
))
#: the negotiation frames, by their kind
NEGOTIATION_MESSAGES = {NegotiationKind.REQUEST: REQUEST, NegotiationKind.CLAIM: CLAIM,
                        NegotiationKind.CANNOT_CLAIM: CANNOT_CLAIM, NegotiationKind.PLAN: PLAN,
                        NegotiationKind.SYNC: SYNC}
