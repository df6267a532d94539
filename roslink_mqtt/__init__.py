"""roslink-mqtt: ROSLink over MQTT — watch and command ROS 2 robots through an ordinary MQTT broker."""

__version__ = "0.1.0"
