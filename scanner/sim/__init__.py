"""Simulators of the scanning site and of the serial devices (GRBL drives, wall scanner)."""
