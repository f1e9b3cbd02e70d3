"""The ``dishbot`` command line: the verbs (``cli.commands``), the client, credentials writing."""
