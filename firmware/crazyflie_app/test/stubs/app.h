/* Host stub: the app layer's entry point. */
#ifndef STUB_APP_H_
#define STUB_APP_H_
void appMain(void);
#endif
