"""The monitor model fed by a Wire: one subscription per registry key (streams on drop lanes)
and a liveliness watch, so it opens fast and a 250 Hz stream cannot back it up."""

from __future__ import annotations

import logging
from pathlib import Path

from drivers.robot.config import default_robot_config
from drivers.sessions.mcap.config import load_session_log_config
from drivers.sessions.recorder import SessionRecorder
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import KEYS, ROOT
from drivers.wire.settings import WireSettings
from drivers.wire.transport import RawSample, Wire

from .config import MonitorConfig, load_monitor_config
from .model import MonitorModel, joint_limits_from_robot

log = logging.getLogger(__name__)


class MonitorSession:
    """A Wire (token `alive/<process>` in `settings.cell_id`) watching `cell` (an id or '*')."""

    def __init__(
        self,
        settings: WireSettings,
        cell: str,
        process: str,
        *,
        config: MonitorConfig | None = None,
        record: Path | None = None,
    ):
        self.config = config or load_monitor_config()
        self.cell = cell
        self.wire = Wire(settings, process)
        self.model = MonitorModel(
            self.config,
            joint_limits_from_robot(default_robot_config()),
            cell=cell,
            ignore_processes=frozenset({(settings.cell_id, process)}),
        )
        self.recorder = None
        try:
            if record is not None:
                log_config = load_session_log_config(settings.config_file)
                self.recorder = SessionRecorder(self.wire, record, log_config, cell=cell)
            for spec in KEYS:
                if spec.kind == "pub":
                    self.wire.subscribe_raw(
                        f"{ROOT}/{cell}/{spec.pattern}",
                        self._on_raw,
                        drop=spec.drop_when_congested,
                        name=f"monitor:{spec.pattern}",
                    )
            self.wire.watch_alive(self.model.on_alive, "alive/*", cell=cell)
        except BaseException:
            self.wire.close()
            raise

    def _on_raw(self, raw: RawSample) -> None:
        if raw.is_delete:
            return
        self.model.on_sample(raw.key, raw.payload, raw.type_name)

    def command(self, command: str, client: str) -> tuple[bool, str, str]:
        """Send a command to the watched cell on `cell/command`: (accepted, text, state after). No reply
        (nobody serves, a timeout, a refusal on the wire) is a refusal whose text says why."""
        request = messages.new("foldcell_msgs/msg/CellCommand", header=messages.header(), command=command,
                               argument="", client=client)
        try:
            reply = self.wire.request("cell/command", request, timeout=self.config.command_timeout_s,
                                      cell=self.cell)
        except WireError as err:
            return False, str(err), ""
        return bool(reply.accepted), str(reply.text), str(reply.state)

    def snapshot(self) -> dict:
        return self.model.snapshot()

    def close(self) -> None:
        self.wire.close()
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> MonitorSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
