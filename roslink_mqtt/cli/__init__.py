"""The ``roslink-mqtt`` command line: one module per subcommand, dispatched by ``main``."""
