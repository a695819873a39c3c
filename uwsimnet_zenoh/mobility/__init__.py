"""Where vehicles are: trajectories and the pose table the channel reads (trajectory.py), and the
kinematic vehicle model that obeys commands (kinematic.py).  Imports kernel/ only."""
