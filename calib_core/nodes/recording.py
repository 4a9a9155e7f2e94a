"""The recorded run, the same for every node that measures or calibrates: one MCAP bag
``<record_dir>/<kind>_<stamp>`` holding every message of the run as it was published, and
(for a calibration) the versioned calibration file that names the bag. The bag is opened
before the first stop, so a run that fails or is killed still replays what it measured; a
run refused before it recorded anything (a plan outside the stroke) leaves no bag.
Beside the run's own messages, a calibrator records each stop's machine frames on ``/tf``
(:mod:`calib_core.nodes.scene`) so a viewer shows the machine moving, and the calibrated
frames the run put in force on ``/tf_static``."""
from __future__ import annotations

import shutil
from datetime import datetime, timezone
from pathlib import Path

from rclpy.serialization import serialize_message

from calib_core.bags import BagWriter
from calib_core.nodes.scene import TF_STATIC_TOPIC, TF_TOPIC, TF_TYPE, transforms_cdr
from calib_core.storage import write_calibration


# A run's stamp: UTC, sorting in time order (calibration files keep it as ``created``).
STAMP_FORMAT = '%Y%m%dT%H%M%S%f'


def run_stamp() -> str:
    """UTC time stamp naming a run's bag, files and reports (sorts in time order)."""
    return datetime.now(timezone.utc).strftime(STAMP_FORMAT)


class RecordedRun:
    """A context manager around one run of ``node``, which declares the ``record_dir``
    (and, to :meth:`save` a calibration, ``output_dir``) parameters.

    Parameters
    ----------
    node : rclpy.node.Node
    kind : str
        Names the bag (``<kind>_<stamp>``) and goes into the calibration file.
    topics : dict
        Topic -> message type (``pkg/msg/Name``) of everything the run records (``/tf``
        and ``/tf_static`` are always declared)."""

    def __init__(self, node, kind: str, topics: dict[str, str]):
        self.node, self.kind = node, kind
        self.topics = {TF_TOPIC: TF_TYPE, TF_STATIC_TOPIC: TF_TYPE, **topics}
        self.stamp = run_stamp()
        self.bag_path = Path(node.get_parameter('record_dir').value) / f'{kind}_{self.stamp}'
        self._bag = None
        self._recorded = 0

    def __enter__(self) -> 'RecordedRun':
        self._bag = BagWriter(self.bag_path).__enter__()
        for topic, msgtype in self.topics.items():
            self._bag.add_topic(topic, msgtype)
        return self

    def __exit__(self, kind, *exc) -> None:
        self._bag.close()
        if kind is not None and self._recorded == 0:
            # Refused before the first message (a plan outside the stroke): an empty bag
            # would only be a run that never happened.
            shutil.rmtree(self.bag_path, ignore_errors=True)

    def record(self, topic: str, msg, publisher=None) -> None:
        """Publish ``msg`` (if a publisher is given) and write it to the bag, stamped now.
        A publisher that puts calibrated frames in force (a CalibratorStatus tap) has its
        /tf_static message written beside it."""
        before = getattr(publisher, 'static_frames', None)
        if publisher is not None:
            publisher.publish(msg)
        now = self.node.get_clock().now().nanoseconds
        self._bag.write(topic, now, serialize_message(msg))
        self._recorded += 1
        frames = getattr(publisher, 'static_frames', None)
        if frames is not None and frames is not before:
            self._bag.write(TF_STATIC_TOPIC, now, serialize_message(frames))

    def record_frames(self, frames: list) -> None:
        """The machine's frames at this stop on ``/tf``: (parent, child, translation (3,)
        m, quaternion (x, y, z, w)) each."""
        now = self.node.get_clock().now().nanoseconds
        self._bag.write(TF_TOPIC, now, transforms_cdr(now, frames))
        self._recorded += 1

    def save(self, name: str, content: dict) -> tuple[Path, int, dict]:
        """Write ``content`` (with this run's kind, stamp and bag added) as the next version
        of calibration file ``name`` in ``output_dir``: (path, version, content written)."""
        content = {'kind': self.kind, 'created': self.stamp, 'bag': str(self.bag_path),
                   **content}
        path, version = write_calibration(self.node.get_parameter('output_dir').value, name,
                                          content)
        return path, version, content
