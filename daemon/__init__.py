"""dishbot daemon: process lifecycle, config, Zenoh, commands, recording, replay, systemd and the CLI."""
