// Focus controller firmware: moves a camera lens through focus planes for holographic display captures.
// Protocol: docs/focus_protocol.md (version 1). Same protocol as `holo focus-sim`.
//
// Hardware (default): a stepper driver with STEP/DIR inputs (A4988, DRV8825, TMC2208 in step/dir mode) on
// the lens' focus ring. Define USE_SERVO to drive a hobby servo instead (positions are then microseconds of
// pulse width, 1000..2000). No libraries are needed for the stepper; the servo uses the bundled Servo library.
//
// Serial: 115200 8N1, ASCII lines ending in '\n'. Opening the port resets the board (DTR); the board prints
//   READY focus_controller 1.0 proto=1 planes=<n>
// when it accepts commands. Requests "<id> <VERB> [ARGS]" are answered "<id> OK ..." or "<id> ERR <CODE> <msg>".

// #define USE_SERVO

#include <Arduino.h>
#ifdef USE_SERVO
#include <Servo.h>
#endif

static const char FIRMWARE_NAME[] = "focus_controller";
static const char FIRMWARE_VERSION[] = "1.0";
static const int PROTOCOL_VERSION = 1;

// ---- configuration: edit for your rig ------------------------------------------------------------------
static const long PLANES[] = {0, 400, 800, 1200, 1600};  // plane k -> position (steps, or servo us)
static const int N_PLANES = sizeof(PLANES) / sizeof(PLANES[0]);
static const long TRAVEL_MIN = 0;
static const long TRAVEL_MAX = 2000;
static const unsigned long SETTLE_MS = 50;     // wait after the last step before reporting SETTLED
#ifdef USE_SERVO
static const int SERVO_PIN = 9;
static const unsigned long SERVO_MOVE_MS = 400;  // a servo gives no feedback: assume it arrives in this time
Servo servo;
#else
static const int STEP_PIN = 2;
static const int DIR_PIN = 3;
static const int ENABLE_PIN = 4;                 // active low on most drivers
static const unsigned long STEP_INTERVAL_US = 800;  // speed: one step every 0.8 ms
#endif
static const int MAX_LINE = 80;

// ---- state ------------------------------------------------------------------------------------------------
static long position = 0;        // current position
static long target = 0;          // where we are going
static unsigned long lastMotionMs = 0;
static unsigned long lastStepUs = 0;
static char line[MAX_LINE + 1];
static int lineLen = 0;
static bool lineTooLong = false;

static bool moving() { return position != target; }

static const char* motionState() {
  if (moving()) return "MOVING";
  if (millis() - lastMotionMs < SETTLE_MS) return "SETTLING";
  return "SETTLED";
}

static void startMove(long to) {
  target = to;
  lastMotionMs = millis();
#ifdef USE_SERVO
  servo.writeMicroseconds((int)to);
#endif
}

static void serviceMotor() {
#ifdef USE_SERVO
  if (moving() && millis() - lastMotionMs >= SERVO_MOVE_MS) {
    position = target;
    lastMotionMs = millis();
  }
#else
  if (!moving()) return;
  unsigned long now = micros();
  if (now - lastStepUs < STEP_INTERVAL_US) return;
  lastStepUs = now;
  digitalWrite(DIR_PIN, target > position ? HIGH : LOW);
  digitalWrite(STEP_PIN, HIGH);
  delayMicroseconds(2);
  digitalWrite(STEP_PIN, LOW);
  position += (target > position) ? 1 : -1;
  lastMotionMs = millis();
#endif
}

static void reply(const char* id, const char* text) {
  Serial.print(id);
  Serial.print(' ');
  Serial.println(text);  // println sends "\r\n"; clients ignore the '\r'
}

static void replyErr(const char* id, const char* code, const char* msg) {
  Serial.print(id);
  Serial.print(" ERR ");
  Serial.print(code);
  Serial.print(' ');
  Serial.println(msg);
}

static bool parseLong(const char* s, long* out) {
  if (s == NULL || *s == '\0') return false;
  char* end;
  long v = strtol(s, &end, 10);
  if (*end != '\0') return false;
  *out = v;
  return true;
}

static bool validId(const char* id) {
  int n = strlen(id);
  if (n < 1 || n > 8) return false;
  for (int i = 0; i < n; i++) if (!isalnum(id[i])) return false;
  return true;
}

static void upcase(char* s) { for (; *s; s++) *s = toupper(*s); }

static void handleLine(char* buf) {
  char* id = strtok(buf, " ");
  if (id == NULL || id[0] == '#') return;
  char* verb = strtok(NULL, " ");
  if (!validId(id) || verb == NULL) { replyErr("?", "SYNTAX", "expected '<id> <VERB> [ARGS]'"); return; }
  upcase(verb);
  char* a1 = strtok(NULL, " ");
  char* a2 = strtok(NULL, " ");
  char* a3 = strtok(NULL, " ");
  char out[64];
  if (!strcmp(verb, "PING")) { reply(id, "OK PONG"); return; }
  if (!strcmp(verb, "VERSION")) {
    snprintf(out, sizeof out, "OK %s %s proto=%d", FIRMWARE_NAME, FIRMWARE_VERSION, PROTOCOL_VERSION);
    reply(id, out);
    return;
  }
  if (!strcmp(verb, "PLANES")) {
    Serial.print(id); Serial.print(" OK n="); Serial.print(N_PLANES); Serial.print(" pos=");
    for (int i = 0; i < N_PLANES; i++) { if (i) Serial.print(','); Serial.print(PLANES[i]); }
    Serial.println();
    return;
  }
  if (!strcmp(verb, "STATUS")) {
    snprintf(out, sizeof out, "OK %s pos=%ld target=%ld", motionState(), position, target);
    reply(id, out);
    return;
  }
  if (!strcmp(verb, "STOP")) {
    target = position;
    lastMotionMs = 0;
    snprintf(out, sizeof out, "OK SETTLED pos=%ld target=%ld", position, target);
    reply(id, out);
    return;
  }
  if (!strcmp(verb, "MOVE")) {
    long v;
    if (a1 != NULL) upcase(a1);
    if (a1 == NULL || a2 == NULL || a3 != NULL || (strcmp(a1, "PLANE") && strcmp(a1, "POS"))) {
      replyErr(id, "ARG", "usage: MOVE PLANE <k> | MOVE POS <steps>");
      return;
    }
    if (!parseLong(a2, &v)) {
      snprintf(out, sizeof out, "not an integer: %.20s", a2);
      replyErr(id, "ARG", out);
      return;
    }
    if (!strcmp(a1, "PLANE")) {
      if (v < 0 || v >= N_PLANES) {
        snprintf(out, sizeof out, "plane must be in [0, %d]", N_PLANES - 1);
        replyErr(id, "RANGE", out);
        return;
      }
      startMove(PLANES[v]);
      snprintf(out, sizeof out, "OK MOVING plane=%ld target=%ld", v, target);
      reply(id, out);
      return;
    }
    if (!strcmp(a1, "POS")) {
      if (v < TRAVEL_MIN || v > TRAVEL_MAX) {
        snprintf(out, sizeof out, "pos must be in [%ld, %ld]", TRAVEL_MIN, TRAVEL_MAX);
        replyErr(id, "RANGE", out);
        return;
      }
      startMove(v);
      snprintf(out, sizeof out, "OK MOVING target=%ld", target);
      reply(id, out);
      return;
    }
  }
  snprintf(out, sizeof out, "unknown command %.20s", verb);
  replyErr(id, "UNKNOWN", out);
}

void setup() {
#ifdef USE_SERVO
  servo.attach(SERVO_PIN);
  position = target = PLANES[0];
  servo.writeMicroseconds((int)position);
#else
  pinMode(STEP_PIN, OUTPUT);
  pinMode(DIR_PIN, OUTPUT);
  pinMode(ENABLE_PIN, OUTPUT);
  digitalWrite(ENABLE_PIN, LOW);
  position = target = 0;  // no end stop: power up with the lens at plane 0 (or add homing here)
#endif
  Serial.begin(115200);
  while (!Serial) {}
  Serial.print("READY "); Serial.print(FIRMWARE_NAME); Serial.print(' '); Serial.print(FIRMWARE_VERSION);
  Serial.print(" proto="); Serial.print(PROTOCOL_VERSION); Serial.print(" planes="); Serial.println(N_PLANES);
}

void loop() {
  serviceMotor();
  while (Serial.available() > 0) {
    char ch = (char)Serial.read();
    if (ch == '\r') continue;
    if (ch == '\n') {
      line[lineLen] = '\0';
      if (lineTooLong) {
        replyErr("?", "SYNTAX", "line longer than 80 characters");
      } else if (lineLen > 0) {
        handleLine(line);
      }
      lineLen = 0;
      lineTooLong = false;
    } else if (lineLen < MAX_LINE) {
      line[lineLen++] = ch;
    } else {
      lineTooLong = true;
    }
    serviceMotor();
  }
}
