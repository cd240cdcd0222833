/* The counted region of benchmarks/instructions.py: callgrind's client requests, which only
   C can issue (a few marker instructions that do nothing outside valgrind). Built by
   instructions.py with the system's C compiler into a temporary folder. */
#include <valgrind/callgrind.h>

void doorlab_region_start(void) {
  CALLGRIND_START_INSTRUMENTATION;
  CALLGRIND_TOGGLE_COLLECT;
}

void doorlab_region_stop(void) {
  CALLGRIND_TOGGLE_COLLECT;
  CALLGRIND_STOP_INSTRUMENTATION;
}
