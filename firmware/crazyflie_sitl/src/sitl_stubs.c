/*
 * sitl_stubs.c - our no-hardware implementations of the small interfaces the compiled firmware modules call:
 * LEDs (led.h, under the firmware's ledseq.c), decks (no deck is ever detected: deck.h, deck_supervisor.h,
 * usddeck.h) and the sound driver. Our own code.
 */
#include <string.h>

#include "FreeRTOS.h"

#include "deck_supervisor.h"
#include "led.h"
#include "sound.h"
#include "usddeck.h"

/* led.h */
static bool leds[LED_NUM];
void ledInit(void) {}
bool ledTest(void) { return true; }
void ledClearAll(void) { memset(leds, 0, sizeof leds); }
void ledSetAll(void) { for (int i = 0; i < LED_NUM; i++) leds[i] = true; }
void ledSet(led_t led, bool value) { if ((int)led >= 0 && led < LED_NUM) leds[led] = value; }
void ledShowFaultPattern(void) {}

/* deck_supervisor.h */
bool deckSupervisorHasFault(void) { return false; }

/* usddeck.h: no uSD deck */
bool usddeckLoggingEnabled(void) { return false; }
enum usddeckLoggingMode_e usddeckLoggingMode(void) { return usddeckLoggingMode_Disabled; }
int usddeckFrequency(void) { return 0; }
void usddeckTriggerLogging(void) {}

/* sound.h */
void soundInit(void) {}
bool soundTest(void) { return true; }
void soundSetEffect(uint32_t effect) { (void)effect; }
void soundSetFreq(uint32_t freq) { (void)freq; }

/* configblock.h: the radio address the localization service reports (the default E7E7E7E7E7) */
uint64_t configblockGetRadioAddress(void) { return 0xE7E7E7E7E7ULL; }
