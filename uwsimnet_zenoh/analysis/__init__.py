"""Traces to numbers, tables and figures: read.py (a JSONL trace back to checked records), metrics.py
(per-flow metrics and the conservation check), tables.py (rich, plain text, markdown, JSON) and figures.py
(matplotlib; import it explicitly).  Above the core's run path (a run never needs it), below the faces;
the one core-level room allowed rich and matplotlib."""

from .levels import LinkLevel
from .metrics import (
    Accumulator,
    Analysis,
    ChannelMetrics,
    Conservation,
    DeviceMap,
    FlowMetrics,
    InFlight,
    analyse,
    conservation,
    flow_metrics,
    flow_name,
)
from .read import (
    DEFAULT_HORIZON,
    EVENTS,
    RX_REASONS,
    TX_REASONS,
    Source,
    TraceError,
    is_int,
    is_num,
    open_source,
    read_trace,
)
from .tables import (
    format_links,
    format_markdown,
    format_report,
    format_text,
    markdown_table,
    report_json,
    show_metrics,
)

__all__ = [
    "Accumulator", "Analysis", "ChannelMetrics",
    "Conservation", "DEFAULT_HORIZON", "DeviceMap", "EVENTS", "FlowMetrics", "InFlight", "LinkLevel",
    "RX_REASONS", "Source", "TX_REASONS", "TraceError", "analyse", "conservation", "flow_metrics", "flow_name",
    "format_links", "format_markdown", "format_report", "format_text", "is_int", "is_num", "markdown_table",
    "open_source", "read_trace", "report_json", "show_metrics"
]
