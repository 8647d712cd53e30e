"""The pure estimation core: arrays and parameters in, arrays out.

Nothing here imports ``can``, ``fastapi`` or reads the clock; time is passed in.
"""
