"""The ``repro`` command: thin argument parsing over the library."""
