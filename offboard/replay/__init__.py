"""Flight logs read back: a MAVLink telemetry log (tlog) into a ``FlightRecord`` and a report.

One idea a module, in the order the data flows:

- ``reader``: ``TlogReader``, the one loader of tlogs (pymavlink decodes; we find where a log
  is damaged and read on past it);
- ``scan``: ``LogScan`` collects, message by message, the series and statistics the rest needs
  (pure), and answers questions about the whole log (the vehicle, its arming, its modes);
- ``record``: ``build_record`` turns a scan into the aligned ``FlightRecord`` that
  ``offboard.metrics`` and ``offboard.plots`` take;
- ``report``: the log's own figures (sources and loss, message rates, events);
- ``stream``: the logged messages re-sent in their original timing;
- ``rerun``: the controller re-run on the recorded telemetry, against the logged commands;
- ``prediction``: how well a flight's latency prediction predicted what the vehicle then reported.

``offboard/commands/replay.py`` is the argv edge. The names below are the public API
(``from offboard.replay import TlogReader``); docs/replay.md describes the command.
"""

from offboard.replay.reader import Damage, LoggedMessage, TlogReader
from offboard.replay.record import (
    SetpointSeries,
    _telemetry_rows,
    build_record,
    logged_scale,
    mode_phases,
    sample_numbers,
    setpoints_for,
)
from offboard.replay.prediction import PredictionCheck, check_prediction
from offboard.replay.report import LogReport, MessageRate, SourceStats, format_log_report, log_report
from offboard.replay.rerun import RERUN_FIELDS, RerunResult, flight_controller, format_rerun, rerun_controller, rerun_panels
from offboard.replay.scan import (
    OFFBOARD_MODE_NAME,
    Event,
    LogScan,
    SeqCounter,
    StreamStats,
    arm_accepted,
    logged_mission_offset,
    offboard_start_s,
    px4_mode_name,
    scan_log,
)
from offboard.replay.stream import stream_log

__all__ = [
    "OFFBOARD_MODE_NAME",
    "PredictionCheck",
    "RERUN_FIELDS",
    "Damage",
    "Event",
    "LogReport",
    "LogScan",
    "LoggedMessage",
    "MessageRate",
    "RerunResult",
    "SeqCounter",
    "SetpointSeries",
    "SourceStats",
    "StreamStats",
    "TlogReader",
    "_telemetry_rows",
    "arm_accepted",
    "build_record",
    "check_prediction",
    "flight_controller",
    "format_log_report",
    "format_rerun",
    "log_report",
    "logged_scale",
    "logged_mission_offset",
    "mode_phases",
    "offboard_start_s",
    "px4_mode_name",
    "rerun_controller",
    "rerun_panels",
    "sample_numbers",
    "scan_log",
    "setpoints_for",
    "stream_log",
]
