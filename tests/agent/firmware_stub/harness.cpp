// Runs the sketch on the host: stdin lines are fed to Serial; "@wait MS" advances the fake clock while
// loop() keeps running (100 us per iteration). Replies go to stdout.
#include "Arduino.h"
unsigned long g_us = 0;
FakeSerial Serial;
#include "focus_controller.ino"

int main() {
  setup();
  char buf[256];
  while (fgets(buf, sizeof buf, stdin)) {
    if (!strncmp(buf, "@wait ", 6)) {
      unsigned long until = g_us + strtoul(buf + 6, NULL, 10) * 1000UL;
      while (g_us < until) { loop(); g_us += 100; }
      continue;
    }
    Serial.in += buf;
    while (Serial.available() > 0) { loop(); g_us += 100; }
    loop();
    fflush(stdout);
  }
  return 0;
}
