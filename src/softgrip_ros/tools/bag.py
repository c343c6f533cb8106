"""rosbag2 logs (a directory: metadata.yaml and MCAP storage, each topic's message definition
embedded), written and read with ``rosbags``, which needs no ROS install: ``ros2 bag info``,
Foxglove and Python all read them. Messages go in as rclpy serialises them (CDR), and come out
as rosbags' own objects (the same field names)."""
from __future__ import annotations

import pathlib

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from softgrip_ros.config_paths import config_dir

CUSTOM_PACKAGES = ("softgrip_interfaces",)


def _message_files(package: str) -> list:
    """The package's .msg files: its installed share, else the source tree's msg_defs/."""
    try:
        from ament_index_python.packages import get_package_share_directory
        share = pathlib.Path(get_package_share_directory(package)) / "msg"
        if share.is_dir():
            return sorted(share.glob("*.msg"))
    except (ImportError, LookupError, ValueError):
        pass
    return sorted((config_dir().parent / "msg_defs" / "msg").glob("*.msg"))


def typestore():
    """ROS 2 Jazzy's standard types, and the suite's own from their .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for package in CUSTOM_PACKAGES:
        for path in _message_files(package):
            types.update(get_types_from_msg(path.read_text(), f"{package}/msg/{path.stem}"))
    store.register(types)
    return store


class BagWriter:
    """``with BagWriter(path) as bag: bag.write(topic, msgtype, stamp_ns, cdr_bytes)``; a
    topic's connection is made at its first message. ``path`` must not exist yet."""

    def __init__(self, path):
        self.path = pathlib.Path(path)
        self.store = typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._connections = {}

    def __enter__(self) -> "BagWriter":
        self._writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self._writer.close()

    def set_custom_data(self, key: str, value: str) -> None:
        """A string in metadata.yaml's custom_data (read back with :func:`custom_data`)."""
        self._writer.set_custom_data(key, value)

    def stamped(self, msgtype: str) -> bool:
        """Whether ``msgtype``'s first field is a std_msgs/Header."""
        fields = self.store.fielddefs.get(msgtype, (None, []))[1]
        return bool(fields) and fields[0][0] == "header"

    def knows(self, msgtype: str) -> bool:
        """Whether messages of ``msgtype`` can be logged (their definition is known)."""
        return msgtype in self.store.fielddefs

    def write(self, topic: str, msgtype: str, stamp_ns: int, data: bytes) -> None:
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.store)
        self._writer.write(connection, int(stamp_ns), data)


def read(path, on_unknown=None):
    """Every message of the log at ``path``, in time order: (topic, msgtype, stamp_ns, message);
    ValueError, in one line, when it is not a readable rosbag2 directory or a part of it is
    damaged (the readers fail in many types on a truncated or corrupt file). A topic whose type
    is neither ROS's nor the suite's (none the tools read) is skipped, and
    ``on_unknown(topic, msgtype)`` hears of it first."""
    store = typestore()
    try:
        with Reader(pathlib.Path(path)) as reader:
            known = [c for c in reader.connections if c.msgtype in store.fielddefs]
            for connection in reader.connections:
                if connection not in known and on_unknown is not None:
                    on_unknown(connection.topic, connection.msgtype)
            if not known:  # rosbags reads every connection when given none
                return
            for connection, stamp_ns, data in reader.messages(connections=known):
                try:
                    message = store.deserialize_cdr(data, connection.msgtype)
                except Exception as error:
                    raise ValueError(f"cannot read the log {path}: a {connection.msgtype} "
                                     f"message on {connection.topic} is damaged "
                                     f"({_one_line(error)})") from None
                yield connection.topic, connection.msgtype, stamp_ns, message
    except ValueError as error:  # ours name the log; rosbags' may not
        text = _one_line(error)
        raise ValueError(text if str(path) in text else f"cannot read the log {path}: {text}"
                         ) from None
    except (FileNotFoundError, NotADirectoryError) as error:
        raise ValueError(f"{path} is not a rosbag2 directory: {_one_line(error)}") from None
    except Exception as error:  # raised by the readers, not by the caller's loop
        raise ValueError(f"cannot read the log {path} (truncated or corrupt?): "
                         f"{_one_line(error)}") from None


def _one_line(error: Exception) -> str:
    text = " ".join(str(error).split())
    return text if isinstance(error, ValueError) and text else f"{type(error).__name__}: {text}"


def note_unknown(topic: str, msgtype: str) -> None:
    """What the tools say of a topic :func:`read` skips."""
    import sys
    print(f"ignoring {topic}: its type {msgtype} is not one the suite reads", file=sys.stderr)


def custom_data(path) -> dict:
    """The custom_data of the log at ``path`` (metadata.yaml; {} when it has none)."""
    import yaml
    try:
        metadata = yaml.safe_load((pathlib.Path(path) / "metadata.yaml").read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise ValueError(f"{path}: no readable metadata.yaml ({_one_line(error)})") from None
    info = (metadata or {}).get("rosbag2_bagfile_information") if isinstance(
        metadata, dict) else None
    custom = (info or {}).get("custom_data") if isinstance(info, dict) else None
    if not isinstance(custom or {}, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in (custom or {}).items()):
        raise ValueError(f"{path}: metadata.yaml's custom_data is not a mapping of strings")
    return dict(custom or {})
