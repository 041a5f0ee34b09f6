// systemd service notifications (sd_notify protocol, without libsystemd):
// READY=1 when the service is up, WATCHDOG=1 heartbeats, STOPPING=1, STATUS=.
// Outside systemd (no NOTIFY_SOCKET) every call is a no-op returning false.
// Thread safe: each call opens, sends on and closes its own socket.
#pragma once

#include <cstdint>
#include <string>

namespace hxmap::rt {

/// Sends `state` (e.g. "READY=1\nSTATUS=mapping") to $NOTIFY_SOCKET. True
/// when sent; false outside systemd or on error.
bool sdNotify(const std::string& state);

/// The watchdog period systemd asks for ($WATCHDOG_USEC, honouring
/// $WATCHDOG_PID), in microseconds; 0 when there is no watchdog.
uint64_t sdWatchdogUsec();

}  // namespace hxmap::rt
