"""gyrolab — MEMS gyroscope temperature testing and drift compensation.

Layers (imports point downward only): ``cli`` → ``report`` → ``compensation`` /
``acquisition`` / ``sim`` → ``recording`` / ``profile`` / small helpers.
"""

__version__ = "0.1.0"
