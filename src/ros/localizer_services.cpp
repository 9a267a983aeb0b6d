// The localizer's services (LocalizerServer::On<Service>), each through Serve; the topics, the
// worker and the diagnostics are in localizer_server.cpp.
#include <stdexcept>

#include "ground_texture_bow/ros/conversions.h"
#include "ground_texture_bow/ros/localizer_server.h"

namespace gtbow_ros {

using ground_texture_bow::Status;

// ---------------------------------------------------------------------------------------------
// Services: always return true; the outcome is in status (cartographer_ros's StatusResponse).

template <typename Body>
Status LocalizerServer::Serve(const char* name, bool any_error_is_input, Body&& body) {
  try {
    return body();
  } catch (const PreconditionFailed& e) {
    return MakeStatus(Status::FAILED_PRECONDITION, e.what());
  } catch (const std::out_of_range& e) {
    return MakeStatus(Status::NOT_FOUND, e.what());
  } catch (const std::invalid_argument& e) {
    Reject(std::string(name) + ": " + e.what(), false);
    return MakeStatus(Status::INVALID_ARGUMENT, e.what());
  } catch (const std::exception& e) {
    if (!any_error_is_input) return MakeStatus(Status::INTERNAL, e.what());
    Reject(std::string(name) + ": " + e.what(), false);
    return MakeStatus(Status::INVALID_ARGUMENT, e.what());
  }
}

void LocalizerServer::ForgetMapState() {
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    edges_.clear();
  }
  mapper_->Reset();
  maintainer_stale_ = true;  // maintenance tracks the new map's keyframes
  backoff_stale_ = true;     // another map: its first passes start again
  std::lock_guard<std::mutex> lock(gate_mutex_);
  gate_.Reset();  // another map: another map -> odom
}

bool LocalizerServer::OnQueryCandidates(ground_texture_bow::QueryCandidates::Request& req,
                                        ground_texture_bow::QueryCandidates::Response& res) {
  res.status = Serve("query_candidates", false, [&] {
    const size_t k =
        req.k > 0 ? req.k : static_cast<size_t>(options_.core.retrieval.verification.candidates);
    std::vector<gtbow::Candidate> cands;
    if (req.use_keyframe_id) {
      cands = localizer_->QueryKeyframe(req.keyframe_id, k, req.verify);
    } else {
      RequireScale();
      cands = localizer_->Query(
          localizer_->Process(ToFloorImage(req.image), gtbow::Localizer::ImageUse::kQuery), k,
          req.verify);
    }
    for (const auto& c : cands) res.candidates.push_back(ToCandidateMsg(c));
    return MakeStatus(Status::OK, std::to_string(cands.size()) + " candidates");
  });
  return true;
}

bool LocalizerServer::OnAddKeyframe(ground_texture_bow::AddKeyframe::Request& req,
                                    ground_texture_bow::AddKeyframe::Response& res) {
  res.status = Serve("add_keyframe", false, [&] {
    if (mode_.load() == Mode::kLocalization) {
      return MakeStatus(Status::FAILED_PRECONDITION,
                        "localization mode: the map is read-only (set_mode first)");
    }
    std::optional<gtbow::Pose2D> pose;
    if (req.has_pose) pose = FromPose2DMsg(req.pose);
    RequireScale();
    const gtbow::ProcessedImage img = localizer_->Process(ToFloorImage(req.image));
    res.id = localizer_->Add(img, ToNanoseconds(req.image.header.stamp), pose);
    changes_++;
    maintainer_stale_ = true;
    return MakeStatus(Status::OK, "keyframe " + std::to_string(res.id) + " with " +
                                      std::to_string(img.features.size()) + " keypoints");
  });
  return true;
}

bool LocalizerServer::OnLocalize(ground_texture_bow::Localize::Request& req,
                                 ground_texture_bow::Localize::Response& res) {
  res.status = Serve("localize", false, [&] {
    RequireScale();
    // As the localization mode localizes a single image (escalating when the preset says so).
    const gtbow::Localization fix = localizer_->LocalizeImage(ToFloorImage(req.image));
    res.localized = fix.success;
    if (!fix.success) return MakeStatus(Status::NOT_FOUND, fix.reason);
    res.pose =
        ToPoseWithCovariance(fix.estimate.floor_from_query, fix.estimate.covariance,
                             req.image.header.stamp, options_.map_frame, options_.planar_variance);
    res.keyframe_id = fix.image;
    res.inliers = static_cast<uint32_t>(fix.estimate.inliers);
    return MakeStatus(Status::OK, "localized against keyframe " + std::to_string(fix.image));
  });
  return true;
}

bool LocalizerServer::OnSaveMap(ground_texture_bow::SaveMap::Request& req,
                                ground_texture_bow::SaveMap::Response& res) {
  res.status = Serve("save_map", true, [&] {
    if (mode_.load() == Mode::kLocalization) {
      // Localization mode never writes a file (set_mode mapping or external to save).
      return MakeStatus(
          Status::FAILED_PRECONDITION,
          "localization mode: the map is read-only and is not saved (set_mode first)");
    }
    if (req.path.empty()) throw std::invalid_argument("empty path");
    CheckAbsolutePath(req.path, "save_map: path");
    const gtbow::SaveStats saved = localizer_->Save(req.path);
    return MakeStatus(Status::OK,
                      "saved " + std::to_string(saved.keyframes) + " keyframes to " + req.path);
  });
  return true;
}

bool LocalizerServer::OnLoadMap(ground_texture_bow::LoadMap::Request& req,
                                ground_texture_bow::LoadMap::Response& res) {
  res.status = Serve("load_map", true, [&] {
    if (req.path.empty()) throw std::invalid_argument("empty path");
    CheckAbsolutePath(req.path, "load_map: path");
    CheckMapFrame(req.path);
    // Without ~meters_per_pixel the map's scale is taken, and the camera's is checked against it.
    const bool adopt = options_.meters_per_pixel <= 0;
    res.keyframes = static_cast<uint32_t>(localizer_->Load(req.path, adopt));
    if (localizer_->pose_frame().empty()) localizer_->SetPoseFrame(options_.map_frame);
    if (adopt) {
      scale_known_ = true;
      scale_from_map_ = true;
      std::lock_guard<std::mutex> lock(state_mutex_);
      scale_source_ = "the map " + req.path;
    }
    if (adopt) WakeWorker();  // an image waiting for camera_info has its scale now
    ForgetMapState();
    return MakeStatus(Status::OK,
                      "loaded " + std::to_string(res.keyframes) + " keyframes from " + req.path);
  });
  return true;
}

bool LocalizerServer::OnReset(ground_texture_bow::Reset::Request&,
                              ground_texture_bow::Reset::Response& res) {
  res.status = Serve("reset", false, [&] {
    if (mode_.load() == Mode::kLocalization) {
      return MakeStatus(Status::FAILED_PRECONDITION, "localization mode: the map is read-only");
    }
    localizer_->Reset();
    scale_from_map_ = false;  // an empty map takes the camera's scale again
    ForgetMapState();
    return MakeStatus(Status::OK, "map cleared");
  });
  return true;
}

bool LocalizerServer::OnGetInfo(ground_texture_bow::GetInfo::Request&,
                                ground_texture_bow::GetInfo::Response& res) {
  res.status = Serve("get_info", false, [&] {
    res.mode = ModeName(mode_.load());
    res.database_size = static_cast<uint32_t>(localizer_->live_size());  // retired: not counted
    res.vocabulary_size = localizer_->vocabulary().size();
    res.vocabulary_path = localizer_->vocabulary_path();
    res.preset = options_.preset;
    res.images_received = received_.load();
    res.images_processed = processed_.load();
    res.images_dropped = dropped_.load();
    res.debug_images = debug_images_.load();
    res.images_rejected = rejected_.load();
    res.requests_rejected = rejected_requests_.load();
    res.fixes = fixes_.load();
    res.loop_closures = loop_closures_.load();
    res.fixes_held = held_fixes_.load();
    res.relocalizations = relocalizations_.load();
    res.sequence_queries = sequence_queries_.load();
    res.meters_per_pixel = scale_known_ ? localizer_->meters_per_pixel() : 0.0;
    res.pose_frame = localizer_->pose_frame();
    res.poses_optimised = localizer_->poses_optimised();
    res.keyframes_reposed = keyframes_reposed_.load();
    res.keyframe_poses_stamp.fromNSec(keyframe_poses_stamp_ns_.load());
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      res.scale_source = scale_source_;
      res.last_error = last_error_;
      res.localized = !last_fix_time_.isZero() &&
                      (ros::Time::now() - last_fix_time_).toSec() <= options_.localized_timeout;
    }
    return MakeStatus(Status::OK, "");
  });
  return true;
}

bool LocalizerServer::OnSetMode(ground_texture_bow::SetMode::Request& req,
                                ground_texture_bow::SetMode::Response& res) {
  res.status = Serve("set_mode", true, [&] {
    const Mode m = ParseMode(req.mode);
    maintainer_stale_ = true;  // keyframes mapped before the switch are tracked
    backoff_stale_ = true;
    res.previous_mode = ModeName(mode_.exchange(m));
    return MakeStatus(Status::OK, "mode " + req.mode);
  });
  return true;
}

}  // namespace gtbow_ros
