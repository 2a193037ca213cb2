"""QGroundControl ``.plan`` files (JSON): the mission part, read and written.

Read: ``fileType`` "Plan" (file ``version`` 1), ``mission`` (``version`` 2) with
``plannedHomePosition`` [lat, lon, alt AMSL], ``hoverSpeed`` (the multicopter cruise speed)
and ``items``, each a ``SimpleItem`` with ``command``, ``frame``, ``params`` (7 numbers, null
meaning NaN, as QGroundControl writes it), ``autoContinue``. ``frame`` and ``params`` are what
the vehicle receives, so they are authoritative; QGroundControl's editing hints
(``Altitude``, ``AltitudeMode``, ``AMSLAltAboveTerrain``) are not interpreted. ``ComplexItem``
entries (survey, corridor scan, structure scan) are refused by name: they are patterns that
QGroundControl expands into simple items only when it uploads them. Geofence and rally
points are ignored (they do not shape the path).

Written: the same layout as QGroundControl's, for a PX4 (``firmwareType`` 12) quadrotor
(``vehicleType`` 2).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from offboard.errors import MissionFormatError
from offboard.missions.fields import read_mission_text
from offboard.missions.items import AMSL_FRAMES, FRAME_GLOBAL, NAV_COMMANDS, ItemMission, MissionItem

#: Values written in ``mission``: MAV_AUTOPILOT_PX4, MAV_TYPE_QUADROTOR.
FIRMWARE_TYPE_PX4 = 12
VEHICLE_TYPE_QUADROTOR = 2
#: QGroundControl's AltitudeMode values for what we write (QGroundControlQmlGlobal::AltMode).
ALTITUDE_MODE_RELATIVE = 1
ALTITUDE_MODE_ABSOLUTE = 2
#: Written as ``cruiseSpeed`` (fixed-wing speed; unused by multicopters) when nothing else is known.
DEFAULT_FIXED_WING_CRUISE_M_S = 15.0


def read_plan(path: str | Path) -> ItemMission:
    """Read the mission of a QGroundControl ``.plan`` file.

    Raises
    ------
    MissionFormatError
        Not JSON, not a Plan, unsupported version, missing or mistyped field, ComplexItem.
    """
    path = Path(path)
    source = path.name
    text = read_mission_text(path, "QGroundControl .plan JSON")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MissionFormatError(f"{source}: line {exc.lineno}: not valid JSON: {exc.msg} (column {exc.colno})") from None

    def fail(where: str, message: str) -> MissionFormatError:
        return MissionFormatError(f"{source}: {where}: {message}")

    def get(obj: Any, key: str, where: str) -> Any:
        if not isinstance(obj, dict):
            raise fail(where, f"expected a JSON object, got {type(obj).__name__}")
        if key not in obj:
            raise fail(f"{where}.{key}" if where != "file" else key, "missing")
        return obj[key]

    def number(value: Any, where: str, *, null_ok: bool = False) -> float:
        if value is None and null_ok:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(where, f"expected a number, got {json.dumps(value)}")
        return float(value)

    file_type = get(doc, "fileType", "file")
    if file_type != "Plan":
        raise fail("fileType", f"expected \"Plan\", got {json.dumps(file_type)}")
    version = get(doc, "version", "file")
    if version != 1:
        raise fail("version", f"expected 1, got {json.dumps(version)}")
    mission = get(doc, "mission", "file")
    mission_version = get(mission, "version", "mission")
    if mission_version != 2:
        raise fail("mission.version", f"expected 2 (QGroundControl 3.2 and later), got {json.dumps(mission_version)}")
    home = get(mission, "plannedHomePosition", "mission")
    if not isinstance(home, list) or len(home) != 3:
        raise fail("mission.plannedHomePosition", f"expected [latitude, longitude, altitude], got {json.dumps(home)}")
    lat, lon, alt = (number(v, f"mission.plannedHomePosition[{k}]") for k, v in enumerate(home))
    hover = mission.get("hoverSpeed")
    hover_speed = None
    if hover is not None:
        hover_speed = number(hover, "mission.hoverSpeed")
        if not hover_speed > 0:
            raise fail("mission.hoverSpeed", f"expected a speed > 0 m/s, got {hover_speed:g}")
    raw_items = get(mission, "items", "mission")
    if not isinstance(raw_items, list) or not raw_items:
        raise fail("mission.items", "expected a non-empty list of mission items")

    items: list[MissionItem] = []
    for i, raw in enumerate(raw_items):
        where = f"mission.items[{i}]"
        kind = get(raw, "type", where)
        if kind == "ComplexItem":
            pattern = raw.get("complexItemType", "unknown")
            raise fail(f"{where} (item {i + 1})", f"type: ComplexItem ({json.dumps(pattern)}) is not supported; expected SimpleItem")
        if kind != "SimpleItem":
            raise fail(f"{where} (item {i + 1})", f"type: expected \"SimpleItem\", got {json.dumps(kind)}")
        where = f"{where} (item {i + 1})"
        command = get(raw, "command", where)
        frame = get(raw, "frame", where)
        for name, value in (("command", command), ("frame", frame)):
            if isinstance(value, bool) or not isinstance(value, int):
                raise fail(where, f"{name}: expected an integer, got {json.dumps(value)}")
        params = get(raw, "params", where)
        if not isinstance(params, list) or len(params) != 7:
            got = f"{len(params)} values" if isinstance(params, list) else json.dumps(params)
            raise fail(where, f"params: expected 7 values (param1..param4, latitude/x, longitude/y, altitude/z), got {got}")
        values = [number(v, f"{where}: params[{k}]", null_ok=True) for k, v in enumerate(params)]
        auto = raw.get("autoContinue", True)
        if not isinstance(auto, bool):
            raise fail(where, f"autoContinue: expected true or false, got {json.dumps(auto)}")
        items.append(
            MissionItem(command, frame, tuple(values[:4]), values[4], values[5], values[6], auto, seq=i + 1, where=where)  # type: ignore[arg-type]
        )
    home_item = MissionItem(16, FRAME_GLOBAL, (0.0, 0.0, 0.0, 0.0), lat, lon, alt, seq=0, where="mission.plannedHomePosition")
    return ItemMission(home_item, tuple(items), source, hover_speed)


def _json_number(value: float) -> float | None:
    return None if math.isnan(value) else value


def plan_document(mission: ItemMission) -> dict[str, Any]:
    """The JSON document of a ``.plan`` for ``mission`` (global home required)."""
    home = mission.home_global
    if home is None:
        raise ValueError(f"{mission.source or 'mission'}: a .plan needs a global home position; this mission is in a local frame")
    items = []
    for seq, item in enumerate(mission.items, start=1):
        entry: dict[str, Any] = {}
        if item.command in NAV_COMMANDS:
            entry["AMSLAltAboveTerrain"] = None
            entry["Altitude"] = _json_number(item.z)
            entry["AltitudeMode"] = ALTITUDE_MODE_ABSOLUTE if item.frame in AMSL_FRAMES else ALTITUDE_MODE_RELATIVE
        entry.update(
            {
                "autoContinue": item.autocontinue,
                "command": item.command,
                "doJumpId": seq,
                "frame": item.frame,
                "params": [_json_number(v) for v in (*item.params, item.x, item.y, item.z)],
                "type": "SimpleItem",
            }
        )
        items.append(entry)
    hover = mission.cruise_speed_m_s
    return {
        "fileType": "Plan",
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "groundStation": "rosales-offboard",
        "mission": {
            "cruiseSpeed": DEFAULT_FIXED_WING_CRUISE_M_S,
            "firmwareType": FIRMWARE_TYPE_PX4,
            "globalPlanAltitudeMode": ALTITUDE_MODE_RELATIVE,
            "hoverSpeed": hover if hover is not None else 5.0,
            "items": items,
            "plannedHomePosition": list(home),
            "vehicleType": VEHICLE_TYPE_QUADROTOR,
            "version": 2,
        },
        "rallyPoints": {"points": [], "version": 2},
        "version": 1,
    }


def write_plan(mission: ItemMission, path: str | Path) -> None:
    """Write ``mission`` as a QGroundControl ``.plan`` (NaN parameters as null, like QGC)."""
    text = json.dumps(plan_document(mission), indent=4, allow_nan=False)
    Path(path).write_text(text + "\n", encoding="utf-8")
