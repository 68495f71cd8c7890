"""MCAP session logs: the writer (chunked, compressed, rotated), reading, `info` and `recover`.

Files follow rosbag2's MCAP conventions so Foxglove and rosbag2 tools open them: profile `ros2`,
schema encoding `ros2msg`, message encoding `cdr`, schema names `pkg/msg/Type`.
"""

from drivers.sessions.mcap.config import SessionLogConfig, session_log_config_from_fields
from drivers.sessions.mcap.errors import LogFileError, LogWriteError, McapLogError, WriterClosedError
from drivers.sessions.mcap.info import ChannelInfo, LogInfo, read_info
from drivers.sessions.mcap.reader import LoggedMessage, iter_messages
from drivers.sessions.mcap.recover import RecoverReport, recover
from drivers.sessions.mcap.writer import SessionWriter, part_path

__all__ = [
    "ChannelInfo", "LogFileError", "LogInfo", "LogWriteError", "LoggedMessage", "McapLogError",
    "RecoverReport", "SessionLogConfig", "SessionWriter", "WriterClosedError", "iter_messages",
    "part_path", "read_info", "recover", "session_log_config_from_fields",
]
