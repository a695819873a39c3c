"""uwsimnet-zenoh: underwater network simulation for HIL robotics, on Zenoh."""
