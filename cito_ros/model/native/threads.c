// Jobs on threads (see cito_native.h).
#include "cito_native.h"

#include <pthread.h>
#include <stdlib.h>

int cito_run_threads(void* (*run)(void*), void* jobs, size_t job_size, int njob) {
  pthread_t* threads = (pthread_t*)calloc(njob > 0 ? njob : 1, sizeof(pthread_t));
  int* started = (int*)calloc(njob > 0 ? njob : 1, sizeof(int));
  if (!threads || !started) {
    free(threads);
    free(started);
    return -1;
  }
  char* job = (char*)jobs;
  // each job on its own thread; a job whose thread cannot start runs on this one
  for (int i = 1; i < njob; i++) {
    started[i] = pthread_create(&threads[i], NULL, run, job + i * job_size) == 0;
  }
  if (njob > 0) run(job);
  for (int i = 1; i < njob; i++) {
    if (started[i]) {
      pthread_join(threads[i], NULL);
    } else {
      run(job + i * job_size);
    }
  }
  free(started);
  free(threads);
  return 0;
}
