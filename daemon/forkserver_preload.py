"""Imported by the multiprocessing forkserver as it starts (``set_forkserver_preload``): from then on the
kernel kills it when the daemon that started it dies (``daemon.lifeline``)."""

from daemon.lifeline import die_with_parent

die_with_parent()
