"""Yaskawa High Speed Ethernet Server packets (UDP, little-endian), shared by the ``hses``
adapter and the emulator. Layout from HARDWARE.md (the manual, not yrcom's offsets).

Header (32 bytes): 'YERC', u16 header size 0x20, u16 payload size, u8 3, u8 division (1 robot),
u8 ack (0 request, 1 answer), u8 request id, u32 block no, 8 bytes '99999999', then the
sub-header: request u16 command, u16 instance, u8 attribute, u8 service, u16 0; answer u8
service|0x80, u8 status, u8 added-status size (in words: 1 for one added-status word), u8 0,
u16 added status, u16 0.

yrcom 0.3.1 reads answers another way (the command echoed at bytes 24-25, status at byte 26,
added status at 30-31). ``decode_answer`` takes the manual's layout when byte 24 echoes the
service, and that other layout when bytes 24-25 echo the command, so a refusal framed either way
is a refusal, never a success; an answer in neither layout is refused.
"""
from __future__ import annotations

import struct
from typing import NamedTuple

HEAD = struct.Struct("<4sHHBBBBI8s")  # 24 bytes
REQ_SUB = struct.Struct("<HHBBH")
ANS_SUB = struct.Struct("<BBBBHH")
MAGIC, RESERVED = b"YERC", b"99999999"
HEADER_SIZE = 0x20

GET_ALL, SET_ALL, GET_ONE, SET_ONE = 0x01, 0x02, 0x0E, 0x10
CMD_ALARM_RESET, CMD_SERVO, CMD_STATUS, CMD_POSITION, CMD_MOVE = 0x82, 0x83, 0x72, 0x75, 0x8A
CMD_ALARM = 0x70  # alarm data reading, instance 1-4 (latest first), 60 bytes
HOLD, SERVO_POWER, HLOCK = 1, 2, 3  # instances of 0x83; data u32 1 on, 2 off
COORD = {"base": 16, "robot": 17, "user": 18, "tool": 19}
POSITION_INSTANCE = 101  # 0x75: robot 1, Cartesian; the manual: answers in the base frame (16)

# status data 1 / data 2 bits
RUNNING, TEACH, PLAY, REMOTE = 0x08, 0x20, 0x40, 0x80
HOLD_MASK, ALARM, ERROR, SERVO = 0x0E, 0x10, 0x20, 0x40
ALARM_RESET, ERROR_CANCEL = 1, 2  # instances of 0x82 (the manual; fs100 RESET_ALARM_TYPE_*)

# added-status codes, the manual's table (moto-hses docs/specs/hses-protocol.md "Added status
# codes"; yrcom's hses_errors.py agrees): 2020 pendant, 2030 playback panel, 2040 external, 2050
# command hold
ADDED_STATUS = {
    0x2010: "the robot is moving: wait for it to stop",
    0x2020: "hold by the programming pendant: release HOLD on the pendant",
    0x2030: "hold by the playback panel: release the hold on the playback panel",
    0x2040: "external hold: release the external hold input (find what set it: a safety "
            "device, the PLC)",
    0x2050: "command hold (HSES hold, command 0x83 instance 1, from this or another PC): "
            "release it with hold off",
    0x2060: "an error or alarm is active: read it on the pendant, fix the cause and reset it",
    0x2070: "servo is off: switch servo power on",
    0x2080: "wrong mode: set the pendant to REMOTE / PLAY",
    0x2100: "command remote is not set: enable command remote on the controller",
    0x3010: "servo power is off: switch servo power on (and check the e-stops)",
    0x3350: "the user frame is not taught: teach it or set robot.hses.user_frame",
    0xA000: "undefined command: is the HSES option enabled on this controller?",
    0xA001: "instance error: the controller has no such instance of this command",
    0xA002: "attribute error",
    0xB003: "data size error: the request's data has the wrong size",
    0xB004: "data out of range",
    0xB008: "control group not accepted: the move names a robot this controller has not",
    0xB009: "speed out of range: lower robot.hses.speed_mm_per_s",
    0xB00B: "coordinate system not accepted: check robot.hses.frame",
    0xB00D: "tool number not accepted: check robot.hses.tool",
    0xB00E: "user frame number not accepted: check robot.hses.user_frame",
}
# status byte without an added status (the manual's status codes). 0x01 comes from yrcom's note
# that a live YRC1000 answers it, added status 0, for most requests it cannot carry out -- but
# yrcom 0.3.1 reads the status a byte late (at byte 26, the added status's size), so a
# manual-layout refusal 0x1F with one added-status word reads 0x01, added 0, through yrcom (an
# outside audit, 2026-11-29, against fs100's parser): most likely yrcom's reading, not the
# controller's; kept as a refusal, with the pendant's status read to say why
STATUS = {
    0x01: "the controller cannot carry out the request in its present state, or the data is "
          "not there (a YRC1000 answers this without saying why: look at the pendant)",
    0x08: "the command is not defined on this controller (firmware, HSES option)",
    0x09: "an invalid element number was found in the data",
    0x28: "the requested instance does not exist for this command",
}
HOLDS = {0x2020: "the programming pendant", 0x2030: "the playback panel",
         0x2040: "an external hold input", 0x2050: "a hold command (0x83 instance 1)"}
HOLD_BITS = ((0x02, 0x2020), (0x04, 0x2040), (0x08, 0x2050))  # status data 2 bit -> added status
RETRYABLE = {0x2010}  # clears by itself


def explain(status: int, added: int) -> str:
    what = ADDED_STATUS.get(added) if added else STATUS.get(status)
    code = f"status 0x{status:02X}, added status 0x{added:04X}"
    return f"{code}: {what}" if what else f"{code} (see the HSES manual's error table)"


class Request(NamedTuple):
    req_id: int
    command: int
    instance: int
    attribute: int
    service: int
    payload: bytes


class Answer(NamedTuple):
    req_id: int
    service: int
    status: int
    added: int
    payload: bytes


def encode_request(req_id: int, command: int, instance: int, attribute: int, service: int,
                   payload: bytes = b"") -> bytes:
    head = HEAD.pack(MAGIC, HEADER_SIZE, len(payload), 3, 1, 0, req_id & 0xFF, 0, RESERVED)
    return head + REQ_SUB.pack(command, instance, attribute, service, 0) + payload


def encode_answer(req_id: int, service: int, status: int = 0, added: int = 0,
                  payload: bytes = b"") -> bytes:
    head = HEAD.pack(MAGIC, HEADER_SIZE, len(payload), 3, 1, 1, req_id & 0xFF, 0x80000000,
                     RESERVED)
    size = 1 if added else 0  # the size counts 16-bit words: one added-status word
    return head + ANS_SUB.pack(service | 0x80, status, size, 0, added, 0) + payload


def _head(data: bytes, ack: int) -> tuple:
    if len(data) < HEADER_SIZE:
        raise ValueError(f"packet of {len(data)} bytes is shorter than the 32-byte header")
    magic, hsize, psize, _, _, got_ack, req_id, _, _ = HEAD.unpack_from(data)
    if magic != MAGIC or hsize != HEADER_SIZE or got_ack != ack:
        raise ValueError(f"not an HSES {'answer' if ack else 'request'}: {data[:12]!r}")
    if len(data) != HEADER_SIZE + psize:
        raise ValueError(f"payload size {psize} does not match {len(data) - HEADER_SIZE} bytes")
    return req_id, data[HEADER_SIZE:]


def decode_request(data: bytes) -> Request:
    req_id, payload = _head(data, 0)
    command, instance, attribute, service, _ = REQ_SUB.unpack_from(data, 24)
    return Request(req_id, command, instance, attribute, service, payload)


def decode_answer(data: bytes, command: int | None = None,
                  service: int | None = None) -> Answer:
    """The answer; with ``command`` and ``service`` (those of the request) the sub-header must
    echo one of them (see the module docstring), else ValueError."""
    req_id, payload = _head(data, 1)
    got_service, status, size, _, added, _ = ANS_SUB.unpack_from(data, 24)
    if service is None or got_service == service | 0x80:
        # the added status is there only where its size says so (a 0x1F with size 0 and stale
        # bytes 28-29 read 0x2010, busy, and the adapter retried to its move timeout)
        return Answer(req_id, got_service & 0x7F, status, added if size else 0, payload)
    if command is not None and struct.unpack_from("<H", data, 24)[0] == command:
        status, size, added = data[26], data[28], struct.unpack_from("<H", data, 30)[0]
        return Answer(req_id, service, status, added if size else 0, payload)
    raise ValueError(f"answer sub-header {data[24:32].hex(' ')} echoes neither service "
                     f"0x{service | 0x80:02X} nor command 0x{command or 0:02X}")


def move_payload(xyz_mm, rxyz_deg, *, coord: int, speed_mm_per_s: float, tool: int,
                 user_frame: int, form: int = 0, expanded_form: int = 0) -> bytes:
    """26 x i32: group, station, speed class 1 (V, 0.1 mm/s), speed, coordinate system,
    X Y Z (um), Rx Ry Rz (0.0001 deg), 2 reserved, type (``form``: the arm's configuration
    bits, front / back, upper / lower arm, flip -- as a position answer gives them), expanded
    type (``expanded_form``: the answer's word 4, axes turned past 180 deg), tool, user frame,
    3 base-axis and 6 station-axis words."""
    words = [1, 0, 1, round(speed_mm_per_s * 10), coord,
             *(round(v * 1000) for v in xyz_mm), *(round(a * 10000) for a in rxyz_deg),
             0, 0, form, expanded_form, tool, user_frame] + [0] * 9
    return struct.pack("<26i", *words)


def unpack_move(payload: bytes) -> dict:
    w = struct.unpack("<26i", payload)
    return {"group": w[0], "speed_class": w[2], "speed_mm_per_s": w[3] / 10, "coord": w[4],
            "xyz_mm": tuple(v / 1000 for v in w[5:8]),
            "rxyz_deg": tuple(v / 10000 for v in w[8:11]), "form": w[13],
            "expanded_form": w[14], "tool": w[15],
            "user_frame": w[16]}


def position_payload(xyz_mm, rxyz_deg, tool: int = 0, form: int = 0,
                     expanded_form: int = 0) -> bytes:
    """13 x i32: data type (16, base frame: the only one 0x75 answers in), form, tool, user
    frame (0), expanded form, X Y Z (um), Rx Ry Rz (0.0001 deg), 7th and 8th axis."""
    return struct.pack("<13i", COORD["base"], form, tool, 0, expanded_form,
                       *(round(v * 1000) for v in xyz_mm),
                       *(round(a * 10000) for a in rxyz_deg), 0, 0)


def unpack_position(payload: bytes, tool: int | None = None) -> tuple[float, float, float]:
    """X Y Z (mm, base frame) of a 0x75 answer; with ``tool``, the answer's tool number (word 2)
    must be it: a position of another tool is of another TCP."""
    if len(payload) < 52:
        raise ValueError(f"position answer of {len(payload)} bytes, expected 52")
    w = struct.unpack_from("<13i", payload)
    if w[0] != COORD["base"]:
        raise ValueError(f"position answer of data type {w[0]}, expected 16 (base frame)")
    if tool is not None and w[2] != tool:
        raise ValueError(f"position answer is of tool {w[2]}, but robot.hses.tool is {tool}: it "
                         "would be the position of another tool centre point; set "
                         "robot.hses.tool to the tool the robot uses, or select the tool on "
                         "the pendant")
    return w[5] / 1000, w[6] / 1000, w[7] / 1000


def unpack_form(payload: bytes) -> tuple[int, int]:
    """The form (word 1: the arm's configuration bits) and the expanded form (word 4: axes
    turned past 180 deg) of a 0x75 position answer: a move that keeps the arm as it stands
    sends both back (``move_payload``'s type and expanded type)."""
    if len(payload) < 52:
        raise ValueError(f"position answer of {len(payload)} bytes, expected 52")
    w = struct.unpack_from("<13i", payload)
    return w[1], w[4]


ALARM_DATA = struct.Struct("<III16s32s")  # code, data, type, time 'YYYY/MM/DD HH:MM', name


def alarm_payload(code: int = 0, data: int = 0, kind: int = 0, time: str = "",
                  name: str = "") -> bytes:
    """60 bytes of 0x70: alarm code, alarm data, alarm type (0: no alarm), time, name."""
    return ALARM_DATA.pack(code, data, kind, time.encode("latin-1")[:16],
                      name.encode("latin-1")[:32])


def unpack_alarm(payload: bytes) -> tuple[int, str]:
    """(alarm code, alarm name); code 0 when no alarm stands."""
    if len(payload) < ALARM_DATA.size:
        raise ValueError(f"alarm answer of {len(payload)} bytes, expected {ALARM_DATA.size}")
    code, _, _, _, name = ALARM_DATA.unpack_from(payload)
    return code, name.rstrip(b"\0").decode("latin-1", "replace").strip()
