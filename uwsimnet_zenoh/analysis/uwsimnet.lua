-- Wireshark dissector for the link-layer header of `uwsimnet pcap` captures (LINKTYPE_USER0, 147).
-- Layout: uwsimnet_zenoh/analysis/pcap.py and docs/view.md.  Use:
--   wireshark -X lua_script:uwsimnet.lua run.pcapng
--   tshark -X lua_script:uwsimnet.lua -r run.pcapng -T fields -e uwsimnet.src -e uwsimnet.rx.outcome
-- or copy this file into Wireshark's personal Lua plugins folder.

local p = Proto("uwsimnet", "uwsimnet frame on air")

local kinds = { [0] = "data", [1] = "ctrl", [255] = "other" }
local outcomes = { [0] = "rx", [1] = "prop", [2] = "col", [3] = "mult", [4] = "range", [5] = "nopose",
                   [255] = "other" }

local f = {
  magic    = ProtoField.string("uwsimnet.magic", "Magic"),
  version  = ProtoField.uint8("uwsimnet.version", "Version"),
  kind     = ProtoField.uint8("uwsimnet.kind", "Kind", base.DEC, kinds),
  hlen     = ProtoField.uint16("uwsimnet.hlen", "Header length"),
  channel  = ProtoField.uint16("uwsimnet.channel", "Channel"),
  src      = ProtoField.uint16("uwsimnet.src", "Source address"),
  dst      = ProtoField.uint16("uwsimnet.dst", "Destination address"),
  attempt  = ProtoField.uint16("uwsimnet.attempt", "Attempt"),
  seq      = ProtoField.uint32("uwsimnet.seq", "Sequence number"),
  size     = ProtoField.uint32("uwsimnet.size", "Bytes on air"),
  txdev    = ProtoField.string("uwsimnet.txdev", "Transmitter"),
  flow     = ProtoField.string("uwsimnet.flow", "Flow"),
  nrx      = ProtoField.uint8("uwsimnet.nrx", "Receivers with an outcome"),
  rx       = ProtoField.none("uwsimnet.rx", "Receiver"),
  rx_dev   = ProtoField.string("uwsimnet.rx.dev", "Receiver"),
  rx_code  = ProtoField.uint8("uwsimnet.rx.code", "Outcome code", base.DEC, outcomes),
  rx_out   = ProtoField.string("uwsimnet.rx.outcome", "Outcome"),
  rx_delay = ProtoField.double("uwsimnet.rx.delay", "Outcome after transmission (s)"),
  rx_dist  = ProtoField.float("uwsimnet.rx.dist", "Distance (m)"),
}
p.fields = { f.magic, f.version, f.kind, f.hlen, f.channel, f.src, f.dst, f.attempt, f.seq, f.size, f.txdev,
             f.flow, f.nrx, f.rx, f.rx_dev, f.rx_code, f.rx_out, f.rx_delay, f.rx_dist }

local function str(tvb, off, tree, field)
  local n = tvb(off, 1):uint()
  if n > 0 then
    tree:add(field, tvb(off + 1, n))
    return off + 1 + n, tvb(off + 1, n):string()
  end
  tree:add(field, tvb(off, 1), "")
  return off + 1, ""
end

function p.dissector(tvb, pinfo, root)
  if tvb:len() < 24 or tvb(0, 4):string() ~= "UWSN" then return 0 end
  pinfo.cols.protocol = "UWSIMNET"
  local t = root:add(p, tvb(0, tvb(6, 2):uint()))
  t:add(f.magic, tvb(0, 4))
  t:add(f.version, tvb(4, 1))
  t:add(f.kind, tvb(5, 1))
  t:add(f.hlen, tvb(6, 2))
  t:add(f.channel, tvb(8, 2))
  t:add(f.src, tvb(10, 2))
  t:add(f.dst, tvb(12, 2))
  t:add(f.attempt, tvb(14, 2))
  t:add(f.seq, tvb(16, 4))
  t:add(f.size, tvb(20, 4))
  local off, txdev, flow = 24, "", ""
  off, txdev = str(tvb, off, t, f.txdev)
  off, flow = str(tvb, off, t, f.flow)
  local n = tvb(off, 1):uint()
  t:add(f.nrx, tvb(off, 1))
  off = off + 1
  local summary = {}
  for _ = 1, n do
    local start = off
    local sub = t:add(f.rx, tvb(off, 1))
    local dev, out
    off, dev = str(tvb, off, sub, f.rx_dev)
    sub:add(f.rx_code, tvb(off, 1))
    off = off + 1
    off, out = str(tvb, off, sub, f.rx_out)
    sub:add(f.rx_delay, tvb(off, 8))
    sub:add(f.rx_dist, tvb(off + 8, 4))
    off = off + 12
    sub:set_len(off - start)
    sub:set_text("Receiver " .. dev .. ": " .. out)
    summary[#summary + 1] = dev .. "=" .. out
  end
  local kind = kinds[tvb(5, 1):uint()] or "?"
  pinfo.cols.src = tostring(tvb(10, 2):uint())
  pinfo.cols.dst = tostring(tvb(12, 2):uint())
  pinfo.cols.info = string.format("%s %s seq %d (try %d) %s -> %s%s [%s]", kind, txdev, tvb(16, 4):uint(),
    tvb(14, 2):uint(), tostring(tvb(10, 2):uint()), tostring(tvb(12, 2):uint()),
    flow ~= "" and (" flow " .. flow) or "", table.concat(summary, " "))
  return off
end

local encap = (wtap_encaps and wtap_encaps.USER0) or (wtap and wtap.USER0) or 45
DissectorTable.get("wtap_encap"):add(encap, p)
