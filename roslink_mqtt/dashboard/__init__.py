"""The web dashboard: a static page that connects to the broker's WebSocket with the user's own login.

``roslink-mqtt dashboard`` runs :class:`DashboardServer`; see docs/dashboard.md.
"""

from .server import DEFAULT_MQTT_JS, DashboardServer, MqttJsMissing, PageConfig

__all__ = ["DEFAULT_MQTT_JS", "DashboardServer", "MqttJsMissing", "PageConfig"]
