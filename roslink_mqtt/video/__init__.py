"""Video from a robot's camera across a thin uplink: the ladder and rate control (ROS-free, PyAV-free), the encoder
and the decoder (PyAV). docs/video.md says how to use it; docs/protocol.md ("Video") what crosses the wire."""
