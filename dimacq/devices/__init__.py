"""Typed device interfaces: one typing.Protocol per device kind."""
