"""Trace records as the run emits them: the `Tracer` and its sinks (JSONL, user callbacks).  Reading traces
back and computing metrics is analysis/'s job.  Imports kernel/ only."""
