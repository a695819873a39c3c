"""ROS 2 without a bridge: rmw_zenoh's wire (keys, liveliness tokens, attachment, RIHS01 hashes, CDR) and
the translation between ROS 2 topics and the simulator's keys, all sans-IO (docs/ros2.md).

    wire.py     keys, tokens, QoS strings, the 33-byte attachment, RIHS01, per-distro rules, ENU <-> NED
    distros.py  the distro names alone (the command line's choices, without the wire)
    cdr.py      CDR through rosbags (the optional extra uwsimnet-zenoh[ros2]); the shipped .msg packages
    bridge.py   nodes/publishers/subscriptions of a run and the message translation both ways
    interfaces/ the ROS 2 package uwsimnet_msgs (Frame, Transmit, Status) and dmac2_interfaces/DMACPayload

The Zenoh glue is bus/ros2.py.
"""
