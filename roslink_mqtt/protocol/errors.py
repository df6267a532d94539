"""The root of roslink-mqtt's exceptions, and the one error type that decoding untrusted input may raise."""


class RoslinkError(Exception):
    """Base of every exception roslink-mqtt raises on purpose: ``except RoslinkError`` catches them all.

    Defined here, at the bottom of the dependency order, so that the protocol's own :class:`ProtocolError`
    (which the SDK lets through when a command's payload is invalid) is one too; the SDK's errors
    (:mod:`roslink_mqtt.client.errors`) derive from it. Where an error used to be a builtin (``ValueError``
    for a bad argument …), its class derives from that builtin too, so code written against the older SDK
    keeps catching it.
    """


class ProtocolError(RoslinkError, ValueError):
    """Untrusted bytes or values did not form a valid ROSLink message.

    Decoders raise nothing else, so a caller can answer every bad input with
    ``str(err)`` on the sender's error topic and carry on. The message names
    what is wrong and where (``payload.lx: expected number, got "fast"``).
    """
