"""What shows a run without being a device: JSON lines, the terminal and live views, the console,
and the ``view`` command's pictures."""
