"""Warp kernels of warpsph, one module per simulation stage.

Installed as ``warpsph.kernels`` (see ``pyproject.toml``). Every module holds small
``@wp.func`` helpers and the ``@wp.kernel`` launches of one stage; the stepper in
:mod:`warpsph.simulation` launches them in the order of the VR paper's Algorithm 2.
"""
