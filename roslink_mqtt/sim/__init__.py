"""A simulated ground robot for demos and tests (no turtlesim on PyPI). Needs the ``[bridge]`` extra."""
