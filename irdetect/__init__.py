"""irdetect: dim point target detection and track initiation in infrared image sequences.

Conventions used everywhere: image stacks are arrays of shape (T, H, W); a point is
(x, y) with x = column and y = row in pixels, the centre of pixel (0, 0) at (0, 0);
a line is rho = x cos(theta) + y sin(theta) with theta in [0, pi); frames count from 0.
"""

__version__ = "0.1.0"
