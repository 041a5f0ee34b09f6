#include <gtest/gtest.h>

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <string>

#include "sd_notify.hpp"

namespace hxmap::rt {
namespace {

// A datagram socket standing in for systemd's notify socket.
class NotifySocket {
 public:
  explicit NotifySocket(const std::string& path) : path_(path) {
    unlink(path_.c_str());
    fd_ = socket(AF_UNIX, SOCK_DGRAM, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path_.c_str(), sizeof(addr.sun_path) - 1);
    ok_ = fd_ >= 0 && bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0;
    timeval tv{2, 0};
    setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  }
  ~NotifySocket() {
    if (fd_ >= 0) close(fd_);
    unlink(path_.c_str());
  }
  bool ok() const { return ok_; }
  std::string receive() {
    char buf[512];
    const ssize_t n = recv(fd_, buf, sizeof(buf), 0);
    return n > 0 ? std::string(buf, static_cast<size_t>(n)) : std::string();
  }

 private:
  std::string path_;
  int fd_ = -1;
  bool ok_ = false;
};

TEST(SdNotify, SendsStatesToTheNotifySocket) {
  const std::string path = "/tmp/hxmap_test_notify_" + std::to_string(getpid());
  NotifySocket sock(path);
  ASSERT_TRUE(sock.ok());
  setenv("NOTIFY_SOCKET", path.c_str(), 1);
  EXPECT_TRUE(sdNotify("READY=1\nSTATUS=playing 35 frames"));
  EXPECT_EQ(sock.receive(), "READY=1\nSTATUS=playing 35 frames");
  EXPECT_TRUE(sdNotify("WATCHDOG=1"));
  EXPECT_EQ(sock.receive(), "WATCHDOG=1");
  unsetenv("NOTIFY_SOCKET");
  EXPECT_FALSE(sdNotify("READY=1")) << "outside systemd: a no-op";
}

TEST(SdNotify, WatchdogPeriodFromTheEnvironment) {
  unsetenv("WATCHDOG_PID");
  unsetenv("WATCHDOG_USEC");
  EXPECT_EQ(sdWatchdogUsec(), 0u);
  setenv("WATCHDOG_USEC", "5000000", 1);
  EXPECT_EQ(sdWatchdogUsec(), 5000000u);
  setenv("WATCHDOG_PID", std::to_string(getpid() + 1).c_str(), 1);
  EXPECT_EQ(sdWatchdogUsec(), 0u) << "meant for another process";
  setenv("WATCHDOG_PID", std::to_string(getpid()).c_str(), 1);
  EXPECT_EQ(sdWatchdogUsec(), 5000000u);
  setenv("WATCHDOG_USEC", "5s", 1);
  EXPECT_EQ(sdWatchdogUsec(), 0u) << "malformed: no watchdog";
  unsetenv("WATCHDOG_PID");
  unsetenv("WATCHDOG_USEC");
}

}  // namespace
}  // namespace hxmap::rt
