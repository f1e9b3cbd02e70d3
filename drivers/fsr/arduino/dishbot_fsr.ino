// dishbot FSR sketch: reads the gripper pad's force-sensing resistor and streams it to the host.
//
// Wiring (thesis §3.2.1): 5V -> FSR -> A0 -> 10 kOhm -> GND, so A0 rises with the force on the pad.
// Output, 100 lines per second at 115200 baud, one per sample:
//   $FSR,<seq>,<raw>*<HH>\r\n
// seq counts samples modulo 65536 (the host spots lost lines), raw is analogRead(A0) in 0..1023, and HH is
// the XOR of every character between '$' and '*' in two upper-case hex digits (as in NMEA 0183).
// The host may send "?V\n" at any time; the sketch answers with
//   $VER,dishbot_fsr,<protocol version>*<HH>\r\n

const uint8_t FSR_PIN = A0;
const unsigned long PERIOD_US = 10000UL;  // 100 Hz
const char VERSION[] = "1";

unsigned long next_sample_us = 0;
uint16_t seq = 0;
char query[8];
uint8_t query_len = 0;

uint8_t checksum(const char *s) {
  uint8_t sum = 0;
  while (*s) sum ^= (uint8_t)*s++;
  return sum;
}

void send_framed(const char *body) {
  char hex[3];
  uint8_t sum = checksum(body);
  const char digits[] = "0123456789ABCDEF";
  hex[0] = digits[sum >> 4];
  hex[1] = digits[sum & 0x0F];
  hex[2] = '\0';
  Serial.print('$');
  Serial.print(body);
  Serial.print('*');
  Serial.print(hex);
  Serial.print("\r\n");
}

void answer_queries() {
  while (Serial.available() > 0) {
    char c = (char)Serial.read();
    if (c == '\n' || c == '\r') {
      query[query_len] = '\0';
      if (strcmp(query, "?V") == 0) {
        char body[32];
        snprintf(body, sizeof(body), "VER,dishbot_fsr,%s", VERSION);
        send_framed(body);
      }
      query_len = 0;
    } else if (query_len < sizeof(query) - 1) {
      query[query_len++] = c;
    } else {
      query_len = 0;  // too long to be a query: drop it
    }
  }
}

void setup() {
  Serial.begin(115200);
  analogReference(DEFAULT);
  next_sample_us = micros();
}

void loop() {
  answer_queries();
  unsigned long now = micros();
  if ((long)(now - next_sample_us) < 0) return;
  next_sample_us += PERIOD_US;
  int raw = analogRead(FSR_PIN);
  char body[24];
  snprintf(body, sizeof(body), "FSR,%u,%d", seq, raw);
  send_framed(body);
  seq++;
}
