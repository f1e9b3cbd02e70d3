"""The wire contract: one declared message per Zenoh key and MCAP topic (``wire.messages``), with its encoder,
decoder and generated JSON Schema (``wire.schemas``)."""
