"""The ROS 2 distros uwsimnet speaks (wire.py has their rules).  Its own module so that `uwsimnet run`
builds the choices of --ros-distro without importing the wire (start-up time)."""

DISTROS = ("humble", "jazzy", "kilted", "lyrical", "rolling")
DEFAULT_DISTRO = "jazzy"
