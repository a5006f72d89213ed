"""The on-device strobe Script of the depthai backend, and the messages the host sends it.

On an OAK-D Pro the IR dot projector and the flood LED are pulsed by the left camera's
strobe; there is no frame-accurate on/off from the host (host commands land ~7 frames
late). So the chip timeline lives on the device: a Script node wakes on every frame event
(MIPI start of frame of sub-frame ``s``) and sets the emitter for the NEXT sub-frame to
``code[(s + 1) % N]``, the same ``chips[sequence % N]`` convention the node uses. Slips of
a frame happen; the demodulator's phase lock measures the real lag from the data.

The host changes the Script's state with one text message on its ``control`` input::

    atris <enabled 0|1> <intensity 0..1> <chips, e.g. 0110>

Every message carries the whole state, so the newest one wins and a dropped message
loses nothing. ``enabled 0`` switches both emitters to 0 at once and keeps them dark.

Every message is also a lease: the Script strobes only while the newest message arrived
at most ``LEASE_FRAMES`` frame events ago; then it keeps the emitters at 0 until the next
message. The host renews the lease at least every ``RENEW_FRAMES`` sub-frames while it
strobes (:class:`drivers.depthai_backend.DepthaiProjector`), so a host that stops, is
killed or hangs leaves the laser lit for at most LEASE_FRAMES frame events after its last
message reached the device (plus that message's few frames on the link): 16 frames,
0.13 s at 120 Hz, 27 ms at 600 Hz.
"""

from __future__ import annotations

from collections.abc import Sequence

from atris_node.errors import ConfigError

#: emitters the Script can strobe
EMITTERS = ("dot", "flood")
#: names of the Script node's inputs
EVENT_INPUT = "event"
CONTROL_INPUT = "control"
#: frame events a control message keeps the Script strobing (the lease)
LEASE_FRAMES = 16
#: sub-frames between the host's renewals while it strobes (well inside the lease, which
#: must also cover the few frames a message takes on the link)
RENEW_FRAMES = 4

_TEMPLATE = '''\
# ATRIS strobe timeline: sets the {emitter} emitter for the NEXT sub-frame on each frame event.
code = {chips!r}
intensity = {intensity!r}
enabled = {enabled!r}
lease = {lease!r}
since = 0


def set_level(level):
    {set_emitter}(level)


def dark():
    Device.setIrLaserDotProjectorIntensity(0.0)
    Device.setIrFloodLightIntensity(0.0)


def apply_state(text):
    global code, intensity, enabled
    words = text.split()
    if len(words) != 4 or words[0] != "atris":
        node.warn("atris strobe: ignored control message " + repr(text))
        return
    enabled = words[1] == "1"
    intensity = min(max(float(words[2]), 0.0), 1.0)
    code = [1 if c == "1" else 0 for c in words[3]] or [0]
    if not enabled:
        dark()


dark()
while True:
    event = node.io["{event}"].get()
    message = node.io["{control}"].tryGet()
    while message is not None:
        apply_state(bytes(message.getData()).decode())
        since = 0
        message = node.io["{control}"].tryGet()
    since += 1
    if enabled and since <= lease:
        chip = code[(event.getSequenceNum() + 1) % len(code)]
        set_level(intensity if chip else 0.0)
    elif enabled:
        set_level(0.0)  # the lease ran out: the host stopped renewing it
'''


def check_chips(chips: Sequence[int]) -> list[int]:
    """The chips as a list of 0/1; raise ConfigError for an empty code or other values."""
    values = [int(c) for c in chips]
    if not values or any(c not in (0, 1) for c in values):
        raise ConfigError(f"a strobe code must be a non-empty sequence of 0/1 chips, got "
                          f"{list(chips)!r}")
    return values


def check_intensity(fraction: float) -> float:
    """``fraction`` as a float in 0..1; raise ConfigError otherwise."""
    if not 0.0 <= fraction <= 1.0:
        raise ConfigError(f"emitter intensity must be within 0..1, got {fraction!r}")
    return float(fraction)


def strobe_script(chips: Sequence[int], emitter: str = "dot", intensity: float = 0.8,
                  enabled: bool = False) -> str:
    """Python source of the on-device Script that strobes ``emitter`` with ``chips``.

    ``chips`` is the code (0 = dark, 1 = lit) indexed by ``sequence % len(chips)``;
    ``intensity`` is the lit level, 0..1 of the emitter's maximum. The Script starts dark
    unless ``enabled``.
    """
    if emitter not in EMITTERS:
        raise ConfigError(f"emitter {emitter!r} is not known; accepted: {', '.join(EMITTERS)}")
    setter = ("Device.setIrLaserDotProjectorIntensity" if emitter == "dot"
              else "Device.setIrFloodLightIntensity")
    return _TEMPLATE.format(emitter=emitter, chips=check_chips(chips),
                            intensity=check_intensity(intensity), enabled=bool(enabled),
                            set_emitter=setter, event=EVENT_INPUT, control=CONTROL_INPUT,
                            lease=LEASE_FRAMES)


def state_message(enabled: bool, intensity: float, chips: Sequence[int]) -> bytes:
    """The control message that sets the Script's whole state."""
    code = "".join(str(c) for c in check_chips(chips))
    return f"atris {int(enabled)} {check_intensity(intensity):.4f} {code}".encode()
