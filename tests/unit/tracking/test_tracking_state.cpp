// The tracking state machine on scripted attempts: which state each frame
// gets, which pose source, whether it is fused, and the run's counts.
#include <gtest/gtest.h>

#include "hxmap/tracking/state.hpp"

namespace hxmap::alg {
namespace {

IcpResult good() {
  IcpResult r;
  r.ok = true;
  r.consistent_ratio = 0.8;
  return r;
}
IcpResult degraded() {
  IcpResult r = good();
  r.consistent_ratio = 0.3;
  r.degraded = "30 % of the associations within the noise gate";
  return r;
}
IcpResult failed(const char* why) {
  IcpResult r;
  r.failure = why;
  return r;
}

TEST(TrackingState, ModelWithinTheNoiseGateIsTrackedAndFused) {
  TrackingStateMachine m;
  EXPECT_TRUE(m.start().fuse);
  const IcpResult model = good();
  const TrackingDecision d = m.update({true, &model, nullptr, nullptr});
  EXPECT_EQ(d.state, TrackingState::kTracked);
  EXPECT_EQ(d.source, PoseSource::kModel);
  EXPECT_TRUE(d.fuse);
  EXPECT_TRUE(d.reason.empty());
}

TEST(TrackingState, DegradedModelMovesThePoseButIsNotFused) {
  TrackingStateMachine m;
  m.start();
  const IcpResult model = degraded();
  const TrackingDecision d = m.update({true, &model, nullptr, nullptr});
  EXPECT_EQ(d.state, TrackingState::kDegraded);
  EXPECT_EQ(d.source, PoseSource::kModel);
  EXPECT_FALSE(d.fuse);
  EXPECT_NE(d.reason.find("noise gate"), std::string::npos) << d.reason;
}

TEST(TrackingState, FrameToFrameFallbackKeepsFollowingAndNamesBothReasons) {
  TrackingStateMachine m;
  m.start();
  const IcpResult model = failed("too few inliers (12)");
  const IcpResult odometry = good();
  const TrackingDecision d = m.update({true, &model, &odometry, nullptr});
  EXPECT_EQ(d.state, TrackingState::kDegraded);
  EXPECT_EQ(d.source, PoseSource::kOdometry);
  EXPECT_FALSE(d.fuse);
  EXPECT_NE(d.reason.find("too few inliers (12)"), std::string::npos) << d.reason;
  EXPECT_EQ(m.counts().odometry_frames, 1u);
}

TEST(TrackingState, LostWhenNothingFollowsAndFrameToFrameIsNotTrustedFromLost) {
  TrackingStateMachine m;
  m.start();
  const IcpResult model = failed("too few inliers (0)");
  const IcpResult odometry_failed = failed("degenerate geometry");
  TrackingDecision d = m.update({true, &model, &odometry_failed, nullptr});
  EXPECT_EQ(d.state, TrackingState::kLost);
  EXPECT_FALSE(d.fuse);
  EXPECT_NE(d.reason.find("degenerate"), std::string::npos) << d.reason;
  // From lost, the previous frame had no pose: odometry from it is not taken.
  const IcpResult odometry = good();
  d = m.update({true, &model, &odometry, nullptr});
  EXPECT_EQ(d.state, TrackingState::kLost);
  // No depth at all.
  d = m.update({false, nullptr, nullptr, nullptr});
  EXPECT_EQ(d.state, TrackingState::kLost);
  EXPECT_EQ(m.consecutiveLost(), 3u);
  // A verified relocalization brings it back, not fused on that frame.
  const IcpResult reloc = good();
  d = m.update({true, &model, nullptr, &reloc});
  EXPECT_EQ(d.state, TrackingState::kTracked);
  EXPECT_EQ(d.source, PoseSource::kRelocalization);
  EXPECT_FALSE(d.fuse);
  // The model confirms: fused again.
  const IcpResult model_ok = good();
  d = m.update({true, &model_ok, nullptr, nullptr});
  EXPECT_TRUE(d.fuse);
  const TrackingCounts& c = m.counts();
  EXPECT_EQ(c.lost, 3u);
  EXPECT_EQ(c.lost_episodes, 1u);
  EXPECT_EQ(c.longest_lost_run, 3u);
  EXPECT_EQ(c.relocalized, 1u);
  EXPECT_EQ(c.tracked, 3u);  // start, relocalized, model
}

TEST(TrackingState, ADegradedModelResultDoesNotEndALoss) {
  TrackingStateMachine m;
  m.start();
  const IcpResult model_failed = failed("too few inliers (0)");
  m.update({true, &model_failed, nullptr, nullptr});
  const IcpResult partial = degraded();
  const TrackingDecision d = m.update({true, &partial, nullptr, nullptr});
  EXPECT_EQ(d.state, TrackingState::kLost);
  EXPECT_NE(d.reason.find("while lost"), std::string::npos) << d.reason;
}

TEST(TrackingState, ModelRecoveryFromLostNeedsNoRelocalization) {
  TrackingStateMachine m;
  m.start();
  const IcpResult model_failed = failed("too few inliers (0)");
  m.update({true, &model_failed, nullptr, nullptr});
  m.update({true, &model_failed, nullptr, nullptr});
  const IcpResult model = good();
  const TrackingDecision d = m.update({true, &model, nullptr, nullptr});
  EXPECT_EQ(d.state, TrackingState::kTracked);
  EXPECT_TRUE(d.fuse);
  EXPECT_EQ(m.counts().lost_episodes, 1u);
  EXPECT_EQ(m.consecutiveLost(), 0u);
}

}  // namespace
}  // namespace hxmap::alg
