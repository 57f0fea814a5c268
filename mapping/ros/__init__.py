"""ROS 2 messages in MCAP: what a scan, a map and a projection session were, for RViz, Foxglove and `ros2 bag`.

`bag.RosBag` writes CDR-encoded ROS 2 messages into an MCAP file (mcap, mcap-ros2-support) and a rosbag2
`metadata.yaml` beside it, so the folder is a rosbag2 (storage mcap). The message definitions it embeds are
shipped as text in msg/: the ROS 2 (Humble) standard ones it uses, and arproj_msgs/ScannerPass, one pass of the
wall scanner. `record` turns a scan, a map and their poses into those messages (see its topics).
"""
