"""The EvoLogics S2C AT command protocol, sans-IO, for both ends of the wire.

`DriverCodec` is the host side (what a driver speaks): it builds commands and turns the modem's
output into events.  `DeviceCodec` is the modem side (what the emulator speaks): it turns a host's
bytes into commands and builds the modem's replies and notifications.  Neither does I/O nor reads a
clock; times are handed in (`now`) where a timeout matters.  Bad input never raises: it becomes a
`ProtocolError` event and the parser resynchronises on the next line.

Wire format (command mode), from the public drivers of the device (EvoLogics `evins` role_at.erl and
`dmac` parser.h, LSTS DUNE Transports/Evologics, DESERT uwinterpreters2c / evologics-drivers):

* host -> modem: `AT<command>` ended by `\\n` on Ethernet (`\\r` on serial); `AT*SEND...` carry binary
  data after the last comma, exactly `<length>` bytes, then the end of line.
* modem -> host: lines ended by `\\r\\n`.  A command gets one synchronous answer (`OK`, a value, a
  multi-line block ended by an empty line for `&V ?S ?P ?ZSL`, or `ERROR <reason>` / `BUSY <reason>`);
  asynchronous notifications may come at any time, between or before answers:

    RECV,<len>,<src>,<dst>,<bitrate>,<rssi>,<integrity>,<ptime us>,<velocity>,<data>
    RECVIM,<len>,<src>,<dst>,ack|noack|force,<duration us>,<rssi>,<integrity>,<velocity>,<data>
    RECVIMS,<len>,<src>,<dst>,<timestamp us>,<duration us>,<rssi>,<integrity>,<velocity>,<data>
    RECVPBM,<len>,<src>,<dst>,<duration us>,<rssi>,<integrity>,<velocity>,<data>
    DELIVERED,<count>,<dst>  FAILED,<count>,<dst>  DELIVEREDIM,<dst>  FAILEDIM,<dst>
    CANCELEDIM,<dst> CANCELEDIMS,<dst> CANCELEDPBM,<dst>  EXPIREDIMS,<dst>
    SENDSTART,<addr>,<type>,<duration>,<delay>  SENDEND,<addr>,<type>,<timestamp>,<duration>
    RECVSTART  RECVEND,<timestamp>,<duration>,<rssi>,<integrity>  RECVFAILED,<velocity>,<rssi>,<integrity>
    BITRATE,<local|remote>,<value>  SRCLEVEL,<n>  RADDR,<addr>  PHYON  PHYOFF  USBLLONG,...  USBLANGLES,...
    ERROR EFAULT / ERROR OVERLOAD (asynchronous errors)

  `RECV*` payloads are binary and may contain `\\r\\n`: the length field says how many bytes follow
  the header, then `\\r\\n` must follow.  The extended form `RECV*,p<pid>,<len>,...` and
  `AT*SEND*,p<pid>,<len>,...` (network protocol id) is accepted on both sides.

Data mode (vendor AT manual 1.7, section 4.2): after `ATO` every host byte is burst data except
`+++AT<command><eol>`; the modem frames answers `+++AT<command>:<len>:<answer>CRLF` and notifications
`+++AT:<len>:<line>CRLF`, and passes received burst data through as it is.  `+++ATC` returns to command mode.
"""


from .device import (
    CRLF,
    TIES_MAX,
    BadCommand,
    Command,
    DeviceCodec,
    DeviceEvent,
    RawData,
    SendCommand,
    bes,
    block,
    busy,
    canceled,
    delivered,
    error,
    failed,
    line,
    notification,
    ok,
    recv,
    recvim,
    recvpbm,
)
from .events import (
    BES_HEAD,
    BROADCAST,
    BURST_MAX,
    DEFERRED,
    IM_FLAGS,
    IM_MAX,
    MAX_LINE,
    MULTILINE,
    RECV_MAX,
    Busy,
    Canceled,
    Data,
    Delivered,
    DriverEvent,
    Error,
    Expired,
    Failed,
    Notification,
    Ok,
    ProtocolError,
    Received,
    Reply,
    request_name,
)
from .host import DriverCodec

__all__ = [
    "BES_HEAD", "BROADCAST", "BURST_MAX", "BadCommand", "Busy", "CRLF", "Canceled", "Command", "DEFERRED", "Data",
    "Delivered", "DeviceCodec", "RawData", "TIES_MAX", "bes",
    "DeviceEvent", "DriverCodec", "DriverEvent", "Error", "Expired", "Failed", "IM_FLAGS", "IM_MAX", "MAX_LINE",
    "MULTILINE", "Notification", "Ok", "ProtocolError", "RECV_MAX", "Received", "Reply", "SendCommand", "block",
    "busy", "canceled", "delivered", "error", "failed", "line", "notification", "ok", "recv", "recvim", "recvpbm",
    "request_name"
]
