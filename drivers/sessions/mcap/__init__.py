"""MCAP session logs: the writer (chunked, compressed, split), reading, `info` and `recover`.

Files follow rosbag2's MCAP conventions so Foxglove and rosbag2 tools open them: profile `ros2`,
schema encoding `ros2msg`, message encoding `cdr`, schema names `pkg/msg/Type`; a session is a
rosbag2 bag folder (bag.py).
"""

from drivers.sessions.mcap.bag import SessionFiles, bag_folder, find_session
from drivers.sessions.mcap.config import SessionLogConfig, session_log_config_from_fields
from drivers.sessions.mcap.errors import LogFileError, LogWriteError, McapLogError, WriterClosedError
from drivers.sessions.mcap.info import ChannelInfo, LogInfo, read_info
from drivers.sessions.mcap.reader import LoggedMessage, iter_messages
from drivers.sessions.mcap.recover import RecoverReport, recover
from drivers.sessions.mcap.session import SessionRecoverReport, read_session_info, recover_bag
from drivers.sessions.mcap.writer import SessionWriter

__all__ = [
    "ChannelInfo", "LogFileError", "LogInfo", "LogWriteError", "LoggedMessage", "McapLogError",
    "RecoverReport", "SessionFiles", "SessionLogConfig", "SessionRecoverReport", "SessionWriter",
    "WriterClosedError", "bag_folder", "find_session", "iter_messages", "read_info", "read_session_info",
    "recover", "recover_bag", "session_log_config_from_fields",
]
