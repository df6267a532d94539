"""The one error type that decoding untrusted input may raise."""


class ProtocolError(ValueError):
    """Untrusted bytes or values did not form a valid ROSLink message.

    Decoders raise nothing else, so a caller can answer every bad input with
    ``str(err)`` on the sender's error topic and carry on. The message names
    what is wrong and where (``payload.lx: expected number, got "fast"``).
    """
