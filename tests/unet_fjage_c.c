/* fjåge's C gateway (org-arl/fjage gateways/c/src, 09c621d) against two nodes of `uwsimnet bridge unet`:
 *   unet_fjage_c PORT_A PORT_B ADDR_B       prints one line of results; exit 0 when every step answered
 *   build: cc -std=gnu99 -O2 -I$SRC -o unet_fjage_c unet_fjage_c.c $SRC/{fjage,jsmn,decode,encode}.c -lm */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fjage.h"

int main(int argc, char* argv[]) {
  if (argc < 4) return 2;
  fjage_gw_t a = fjage_tcp_open("127.0.0.1", atoi(argv[1]));
  fjage_gw_t b = fjage_tcp_open("127.0.0.1", atoi(argv[2]));
  if (a == NULL || b == NULL) { printf("CONNECT FAILED\n"); return 1; }
  fjage_aid_t node = fjage_agent_for_service(a, "org.arl.unet.Services.NODE_INFO");
  fjage_aid_t phy = fjage_agent_for_service(a, "org.arl.unet.Services.PHYSICAL");
  fjage_aid_t phyb = fjage_agent_for_service(b, "org.arl.unet.Services.PHYSICAL");
  if (node == NULL || phy == NULL || phyb == NULL) { printf("NO AGENTS\n"); return 1; }
  int address = fjage_param_get_int(a, node, "address", -1, -1);
  char name[32] = "";
  fjage_param_get_string(a, node, "nodeName", -1, name, sizeof(name));
  int mtu = fjage_param_get_int(a, phy, "MTU", -1, -1);
  float rate = fjage_param_get_float(a, phy, "dataRate", 2, -1);
  fjage_subscribe_agent(b, phyb);
  fjage_msg_t req = fjage_msg_create("org.arl.unet.DatagramReq", FJAGE_REQUEST);
  fjage_msg_set_recipient(req, phy);
  fjage_msg_add_int(req, "to", atoi(argv[3]));
  fjage_msg_add_int(req, "protocol", 32);
  uint8_t data[] = {1, 2, 3, 200};
  fjage_msg_add_byte_array(req, "data", data, sizeof(data));
  fjage_msg_t rsp = fjage_request(a, req, 5000);
  int agree = rsp != NULL && fjage_msg_get_performative(rsp) == FJAGE_AGREE;
  if (rsp != NULL) fjage_msg_destroy(rsp);
  fjage_msg_t ntf = fjage_receive(b, "org.arl.unet.DatagramNtf", NULL, 5000);
  int from = -1, n = -1;
  long dt = -1;
  uint8_t got[16];
  if (ntf != NULL) {
    from = fjage_msg_get_int(ntf, "from", -1);
    n = fjage_msg_get_byte_array(ntf, "data", got, sizeof(got));
    dt = fjage_msg_get_long(ntf, "rxTime", 0) - fjage_msg_get_long(ntf, "txTime", 0);
    fjage_msg_destroy(ntf);
  }
  printf("address=%d nodeName=%s MTU=%d dataRate=%.0f agree=%d from=%d n=%d data=%d,%d,%d,%d dt_us=%ld\n", address,
         name, mtu, rate, agree, from, n, n > 3 ? got[0] : -1, n > 3 ? got[1] : -1, n > 3 ? got[2] : -1,
         n > 3 ? got[3] : -1, dt);
  fjage_close(a);
  fjage_close(b);
  return (agree && ntf != NULL) ? 0 : 1;
}
