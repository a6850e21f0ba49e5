// The server's Prometheus metrics, in the text exposition format (version 0.0.4), for
// tandem-server --metrics-listen. Names follow Prometheus' conventions: a `tandem_`
// prefix, `_total` on counters, base units (seconds, bytes). Rendering only reads atomics
// and takes the state's lock for the worker count: a scrape never waits on a session.
#ifndef TANDEM_SERVER_METRICS_H_
#define TANDEM_SERVER_METRICS_H_

#include <string>

#include "tandem/server/service_state.h"

namespace tandem::server {

std::string PrometheusText(const ServiceState& state);

}  // namespace tandem::server

#endif  // TANDEM_SERVER_METRICS_H_
