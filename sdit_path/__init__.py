"""sdit-path: plan spatial double-ball-bar identification tests (SDIT) and write the NC
programs that run them."""

__version__ = "0.1.0"
