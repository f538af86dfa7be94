"""Hardware-in-the-loop: the native firmware over a pseudo-terminal, checked against the host."""
