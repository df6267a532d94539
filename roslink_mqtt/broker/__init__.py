"""The embedded MQTT broker (extra ``[broker]``): amqtt 0.12.1, hardened, with fleet logins and ROSLink ACLs.

Modules, one job each:

* :mod:`.acl` -- who may publish, subscribe and receive what (pure logic, no amqtt)
* :mod:`.ratelimit` -- failed-login throttling per client address (pure logic)
* :mod:`.export` -- the same rules as a Mosquitto password file, ACL file and config (no amqtt)
* :mod:`.hardened` -- amqtt's Broker with its 0.12.1 gaps closed (keep-alive, retained ACL, QoS, ...)
* :mod:`.plugins` -- amqtt auth, topic-ACL and ``$SYS`` plugins backed by the fleet
* :mod:`.server` -- one fleet's broker: listeners, plugin wiring, reload
* :mod:`.main` -- the ``roslink-mqtt-broker`` command (also ``python -m roslink_mqtt.broker``)

Importing this package imports nothing from amqtt, so the CLI's ``acl export`` works on a
client install.
"""
