"""Log files: format detection (``detect``), the reader base (``base``), its backends (``rosbags`` for ROS 1 and
ROS 2 bags, ``mcap`` for bare MCAP; ``bag1_index`` and ``bag1_raw`` read ROS 1 bags fast), ``open_log``
(``reader``), the writer, and copies of connections and messages as stored (``copy``)."""
