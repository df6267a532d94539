"""``python -m roslink_mqtt.broker`` = ``roslink-mqtt-broker``."""

import sys

from .main import main

sys.exit(main())
