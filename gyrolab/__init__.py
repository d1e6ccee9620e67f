"""gyrolab — MEMS gyroscope temperature testing and drift compensation.

Layers (imports point downward only; docs/architecture.md, tests/test_architecture.py):
``cli`` → ``app`` → ``report`` / ``export`` / ``batch`` / ``convert`` → ``compensation`` /
``acquisition`` / ``sim`` / ``logs`` → ``instruments`` → ``record`` / ``profiles`` →
``numerics`` → the floor (errors, outputs, progress, tomlfile, pt100, framing, clock).
"""

__version__ = "0.1.0"
