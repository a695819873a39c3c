"""Flows that act like applications (periodic or Poisson sources on a modem).  Imports the core rooms
below it only."""
