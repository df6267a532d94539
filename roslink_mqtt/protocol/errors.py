"""The root of roslink-mqtt's exceptions, and the one error type that decoding untrusted input may raise."""

from __future__ import annotations


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

    ``request_id`` and ``client_id``: what the malformed request said about itself, when its parser got that
    far, so the refusal is addressed to its sender and names the request without parsing the payload again.
    """

    request_id: str | int | None = None
    client_id: str | None = None

    def naming(self, request_id: str | int | None, client_id: str | None) -> ProtocolError:
        """This error, saying which request it is about (``raise err.naming(rid, sender)``)."""
        self.request_id, self.client_id = request_id, client_id
        return self
