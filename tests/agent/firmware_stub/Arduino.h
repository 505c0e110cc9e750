// Minimal host stand-in for the Arduino core, enough to compile and drive the focus controller sketch in
// tests (tests/agent/test_firmware.py): a fake clock, no-op pins, and a Serial fed from a string.
#pragma once
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#define HIGH 1
#define LOW 0
#define OUTPUT 1

extern unsigned long g_us;
inline unsigned long micros() { return g_us; }
inline unsigned long millis() { return g_us / 1000UL; }
inline void delayMicroseconds(unsigned int) {}
inline void pinMode(int, int) {}
inline void digitalWrite(int, int) {}

struct FakeSerial {
  std::string in;
  size_t pos = 0;
  void begin(long) {}
  explicit operator bool() const { return true; }
  int available() { return (int)(in.size() - pos); }
  int read() { return pos < in.size() ? (unsigned char)in[pos++] : -1; }
  void print(const char* s) { fputs(s, stdout); }
  void print(char c) { fputc(c, stdout); }
  void print(int v) { printf("%d", v); }
  void print(long v) { printf("%ld", v); }
  void println(const char* s) { print(s); fputs("\r\n", stdout); }
  void println(int v) { print(v); fputs("\r\n", stdout); }
  void println() { fputs("\r\n", stdout); }
};
extern FakeSerial Serial;
