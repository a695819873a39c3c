// Prints DcMacPacket buffers built by the real DcMac code (dccomms_examples 3cfb74d src/DcMac.cpp:1-249 and its
// DcMac.h, unmodified, compiled with dccomms 45189e2 Packet.cpp + Checksum.cpp) as JSON lines: tests/data/dcmac_vectors.json.
#include <dccomms_examples/DcMac.h>
#include <cstdio>
using namespace dccomms_examples;
static void dump(const char *name, DcMacPacket &p) {
  printf("{\"name\": \"%s\", \"size\": %d, \"hex\": \"", name, p.GetPacketSize());
  uint8_t *b = p.GetBuffer();
  for (int i = 0; i < p.GetPacketSize(); i++) printf("%02x", b[i]);
  printf("\", \"ok\": %s}\n", p.PacketIsOk() ? "true" : "false");
}
int main() {
  { DcMacPacket p; p.SetDst(2); p.SetSrc(1); uint8_t d[] = "hello"; p.SetPayload(d, 5); p.UpdateFCS(); dump("data 1->2 hello", p); }
  { DcMacPacket p; p.SetDst(4); p.SetSrc(3); uint8_t d[1500]; for (int i = 0; i < 1500; i++) d[i] = i * 7; p.SetPayload(d, 1500); p.UpdateFCS(); dump("data 3->4 1500 bytes i*7", p); }
  { DcMacPacket p; p.SetDst(15); p.SetSrc(0); p.SetPayload((uint8_t*)"", 0); p.UpdateFCS(); dump("data 0->15 empty", p); }
  { DcMacPacket p; p.SetType(DcMacPacket::rts); p.SetDst(0); p.SetSrc(1); p.SetRtsDataSize(301); p.SetSlaveAckMask(5); p.UpdateFCS(); dump("rts 1->0 size 301 ack 5", p); }
  { DcMacPacket p; p.SetType(DcMacPacket::cts); p.SetDst(2); p.SetSrc(0); p.SetRtsDataSize(4094); p.UpdateFCS(); dump("cts 0->2 size 4094", p); }
  { DcMacPacket p; p.SetType(DcMacPacket::sync); p.SetDst(0); p.SetSrc(0); p.SetMasterAckMask(0x0a); p.UpdateFCS(); dump("sync mask 0x0a", p); }
  return 0;
}
