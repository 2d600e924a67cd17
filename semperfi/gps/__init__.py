"""L1 C/A physics from IS-GPS-200: codes, navigation message, orbits, time. numpy only, no I/O."""
