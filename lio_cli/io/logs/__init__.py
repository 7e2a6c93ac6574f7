"""Log files: format detection, the reader base and one backend per kind (ROS 1, rosbags, MCAP), the writer,
and copies of connections and messages as stored."""
