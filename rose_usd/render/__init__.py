"""Mitsuba 3 rendering: the renderer of the SSIM gate and of the synthetic case generator.

Importing this package does not import Mitsuba; :func:`rose_usd.render.variant.mitsuba` does.
"""
