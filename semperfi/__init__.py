"""SemperFi: a spoofer-eliminating GPS L1 C/A software receiver, and the world it is proven against."""

__version__ = "0.1.0"
