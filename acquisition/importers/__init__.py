"""Importers of field recordings (``imustation import``; docs/import.md): ROS bags, MCAP, text logs, arrays.

They acquire data into run-file format v1 as a capture does, from a recording
instead of a bus. Offers:

* :func:`import_recording` - a recording -> a run file (:mod:`.loop`, the one write loop);
* :func:`stream_recording` - the same loop into arrays in memory, no file (:mod:`.stream`; ``analyze``);
* :func:`source_kind`, :func:`is_field_input` - what a path is (:mod:`.sources`);
* :func:`text_mapping` - the columns of a text log (:mod:`.logs`);
* :class:`StampChecker`, :func:`check_stamps` - timestamp hygiene (:mod:`.timestamps`).

Readers, one module per source: :mod:`.bags` (which bag reader, topics) over
:mod:`.ros1` (imustation's streaming ROS 1 readers: bags, :mod:`.rosbag1`, and MCAP of
ROS 1 messages, :mod:`.mcap1`) and :mod:`.ros2` (rosbags: ROS 2 bags, ROS 2 MCAP);
:mod:`.logs` (text logs, .npy; their units: :mod:`.units`, exact time cells:
:mod:`.textcells`); :mod:`.messages` decodes sensor_msgs/Imu and /Temperature with numpy.
"""

from imustation.acquisition.importers.logs import TextMapping, text_mapping
from imustation.acquisition.importers.loop import ImportResult, import_recording
from imustation.acquisition.importers.sources import is_field_input, source_kind
from imustation.acquisition.importers.stream import StreamedDevice, StreamedRecording, stream_recording
from imustation.acquisition.importers.timestamps import StampChecker, StampReport, check_stamps

__all__ = [
    "ImportResult",
    "StampChecker",
    "StampReport",
    "StreamedDevice",
    "StreamedRecording",
    "TextMapping",
    "check_stamps",
    "import_recording",
    "is_field_input",
    "source_kind",
    "stream_recording",
    "text_mapping",
]
