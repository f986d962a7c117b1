/*
 * sitl_link.c - the CRTP link over UDP (WIRE.md "CRTP"), in place of the radio link. The firmware's comm.c is
 * compiled unmodified and calls crtpSetLink(radiolinkGetLink()): our radiolinkGetLink() returns this link.
 * Also the rest of the radio/USB/syslink interfaces comm.c and platformservice.c call (our own implementations).
 *
 * One CRTP packet per datagram (header byte + payload). Replies go to the address the last datagram came from. The
 * link counts as connected while datagrams arrive (CONFIG_RADIO_ACTIVITY_TIMEOUT_MS, as the radio link). The null
 * packet (header 0xFF) only marks the link connected; 0xFF 0xFE <cmd> is the nRF51's power command (cflib's
 * PowerSwitch), echoed back as the answer PowerSwitch waits for: 0xF0 reboot -> exit 3, 0x02 off -> exit 4.
 *
 * The POSIX port runs one FreeRTOS task at a time on host threads, so no task may block in a system call: the
 * socket is non-blocking and the receiving task polls it once per tick.
 */
#include <errno.h>
#include <string.h>
#include <sys/socket.h>
#include <netinet/in.h>

#include "FreeRTOS.h"
#include "task.h"

#include "autoconf.h"
#include "crtp.h"
#include "radiolink.h"
#include "syslink.h"
#include "uart_syslink.h"
#include "usblink.h"

#include "sitl.h"

#ifdef CONFIG_RADIO_ACTIVITY_TIMEOUT_MS
#define SITL_LINK_TIMEOUT_MS CONFIG_RADIO_ACTIVITY_TIMEOUT_MS
#else
#define SITL_LINK_TIMEOUT_MS 1000
#endif

#define POWER_CMD_MARKER 0xFE
#define POWER_CMD_OFF 0x02
#define POWER_CMD_REBOOT 0xF0

int sitlCrtpSocket = -1;

static struct sockaddr_in peer;
static bool havePeer;
static bool everReceived;
static uint32_t lastRxTick;
static uint32_t rxCount, txCount, txDropped;

static bool linkIsConnected(void) {
  return everReceived && (xTaskGetTickCount() - lastRxTick) < M2T(SITL_LINK_TIMEOUT_MS);
}

static int linkSetEnable(bool enable) {
  (void)enable;
  return 0;
}

/* Returns true when the packet is gone (sent), false to make crtpTxTask keep it and retry 10 ms later: while no
 * client is connected the TX queue fills up and non-blocking sends fail, as with the radio. */
static int linkSendPacket(CRTPPacket *p) {
  if (!havePeer || !linkIsConnected()) {
    return false;
  }
  uint8_t raw[CRTP_MAX_DATA_SIZE + 1];
  size_t size = p->size <= CRTP_MAX_DATA_SIZE ? p->size : CRTP_MAX_DATA_SIZE;
  raw[0] = p->header;
  memcpy(&raw[1], p->data, size);
  for (;;) {
    ssize_t n = sendto(sitlCrtpSocket, raw, size + 1, 0, (const struct sockaddr *)&peer, sizeof peer);
    if (n >= 0) {
      txCount++;
      return true;
    }
    if (errno == EINTR) {
      continue;
    }
    if (errno == EAGAIN || errno == EWOULDBLOCK || errno == ENOBUFS) {
      return false; /* retried by crtpTxTask */
    }
    txDropped++; /* e.g. ECONNREFUSED from an earlier datagram to a closed port: drop this packet */
    return true;
  }
}

static void handlePowerCommand(const uint8_t *data, ssize_t n, const struct sockaddr_in *from) {
  if (n >= 3 && data[1] == POWER_CMD_MARKER) {
    /* cflib's PowerSwitch waits for an answer to each command (on the radio: the nRF51's ack): echo it. */
    ssize_t ignored = sendto(sitlCrtpSocket, data, (size_t)n, 0, (const struct sockaddr *)from, sizeof *from);
    (void)ignored;
    if (data[2] == POWER_CMD_REBOOT) {
      sitlLog("LINK: reboot requested (PowerSwitch)\n");
      sitlExit(SITL_EXIT_REBOOT);
    } else if (data[2] == POWER_CMD_OFF) {
      sitlLog("LINK: power off requested (PowerSwitch)\n");
      sitlExit(SITL_EXIT_POWER_OFF);
    }
  }
}

static int linkReceivePacket(CRTPPacket *p) {
  uint8_t data[64];
  for (;;) {
    struct sockaddr_in from;
    socklen_t fromLength = sizeof from;
    ssize_t n = recvfrom(sitlCrtpSocket, data, sizeof data, 0, (struct sockaddr *)&from, &fromLength);
    if (n < 0) {
      if (errno != EINTR) {
        vTaskDelay(1); /* nothing there (EAGAIN): poll again next tick */
      }
      continue;
    }
    if (n == 0) {
      continue;
    }
    taskENTER_CRITICAL();
    peer = from;
    havePeer = true;
    everReceived = true;
    lastRxTick = xTaskGetTickCount();
    taskEXIT_CRITICAL();
    rxCount++;
    if (data[0] == 0xFF) {
      handlePowerCommand(data, n, &from); /* the null packet: link keep-alive, never routed */
      continue;
    }
    size_t size = (size_t)(n - 1);
    if (size > CRTP_MAX_DATA_SIZE) {
      size = CRTP_MAX_DATA_SIZE;
    }
    memset(p, 0, sizeof *p);
    p->header = data[0];
    p->size = (uint8_t)size;
    memcpy(p->data, &data[1], size);
    return 0;
  }
}

static int linkReset(void) { return 0; }

static struct crtpLinkOperations udpLink = {
  .setEnable = linkSetEnable,
  .sendPacket = linkSendPacket,
  .receivePacket = linkReceivePacket,
  .isConnected = linkIsConnected,
  .reset = linkReset,
};

/* ---------------------------------------------------------------------------------------- radiolink.h */

void radiolinkInit(void) {}
bool radiolinkTest(void) { return sitlCrtpSocket >= 0; }
struct crtpLinkOperations *radiolinkGetLink(void) { return &udpLink; }
void radiolinkSetChannel(uint8_t channel) { (void)channel; }
void radiolinkSetDatarate(uint8_t datarate) { (void)datarate; }
void radiolinkSetAddress(uint64_t address) { (void)address; }
void radiolinkSetPowerDbm(int8_t powerDbm) { (void)powerDbm; }
void radiolinkSyslinkDispatch(SyslinkPacket *slp) { (void)slp; }
bool radiolinkSendP2PPacketBroadcast(P2PPacket *p2pp) { (void)p2pp; return false; }
void p2pRegisterCB(P2PCallback cb) { (void)cb; }

/* ---------------------------------------------------------------------------------------- uart_syslink.h */

void uartslkInit(void) {}
bool uartslkTest(void) { return true; }
void uartslkEnableIncoming(void) {}

/* ---------------------------------------------------------------------------------------- syslink.h */

int syslinkSendPacket(SyslinkPacket *slp) { (void)slp; return 0; }
bool isSyslinkUp(void) { return true; }

/* ---------------------------------------------------------------------------------------- usblink.h */

void usblinkInit(void) {}
bool usblinkTest(void) { return true; }
