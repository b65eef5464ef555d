"""Exact scaled integer division for the chip simulators: ``muldiv(a, b, d, add, shift)`` =
floor((((a * b) << shift) + add) / d).

On the QEMU board image (ports/mps2, a 32-bit MicroPython) the intermediates exceed small ints
and would be heap-allocated inside the firmware's heap-locked cycle, so the image supplies it in
C (ports/mps2/modsimint.c); elsewhere plain Python integers do it.
"""
try:
    from simint import muldiv  # type: ignore
except ImportError:
    def muldiv(a, b, d, add=0, shift=0):
        return (((a * b) << shift) + add) // d
