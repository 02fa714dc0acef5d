// The picture-making programs as a user runs them: sinew-demo --render and --video, and sinew-view
// started under Xvfb, taking a screenshot and exiting. Each output is read back and checked.
#include "sinew/types.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#define STB_IMAGE_IMPLEMENTATION
#include <stb/stb_image.h>

namespace sinew {
namespace {

namespace fs = std::filesystem;

fs::path out_dir(const std::string& name) {
  const fs::path dir = fs::path(SINEW_TEST_OUT) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

int run(const std::string& command) { return std::system((command + " > /dev/null 2>&1").c_str()); }

std::string head(const fs::path& file, std::size_t n) {
  std::ifstream in(file, std::ios::binary);
  std::string s(n, '\0');
  in.read(s.data(), static_cast<std::streamsize>(n));
  return s;
}

// Loads a PNG and checks its size and that it is a picture: many shades, not one flat colour, and some
// cloth-coloured pixels (blue in front, ochre behind, both far from the grey ground and pale sky).
void expect_picture(const fs::path& file, int width, int height) {
  int w = 0, h = 0, channels = 0;
  unsigned char* data = stbi_load(file.string().c_str(), &w, &h, &channels, 3);
  ASSERT_NE(data, nullptr) << file << ": not a readable image";
  EXPECT_EQ(w, width) << file;
  EXPECT_EQ(h, height) << file;
  long saturated = 0;
  double sum = 0, sum2 = 0;
  for (int i = 0; i < w * h; ++i) {
    const int r = data[3 * i], g = data[3 * i + 1], b = data[3 * i + 2];
    const int spread = std::max({r, g, b}) - std::min({r, g, b});
    if (spread > 60) ++saturated;
    sum += g;
    sum2 += double(g) * g;
  }
  stbi_image_free(data);
  const double mean = sum / (w * h), variance = sum2 / (w * h) - mean * mean;
  EXPECT_GT(variance, 50.0) << file << ": nearly one colour";
  EXPECT_GT(saturated, w * h / 200) << file << ": no cloth-coloured pixels";
}

TEST(DemoRender, WritesOnePicturePerFrame) {
  const fs::path dir = out_dir("render");
  ASSERT_EQ(run(std::string(SINEW_DEMO) + " hello --frames 3 --size 200x120 --render " + dir.string()), 0);
  for (int f = 1; f <= 3; ++f) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.png", f);
    expect_picture(dir / name, 200, 120);
  }
  EXPECT_FALSE(fs::exists(dir / "frame_0004.png"));
}

TEST(DemoRender, AFileWhereTheFolderShouldBeIsNamed) {
  const fs::path dir = out_dir("not-a-folder");
  std::ofstream(dir / "taken") << "x";
  const std::string log = (dir / "log.txt").string();
  const int status = std::system((std::string(SINEW_DEMO) + " hello --frames 1 --size 64x48 --render " +
                                  (dir / "taken").string() + " > " + log + " 2>&1")
                                     .c_str());
  EXPECT_NE(status, 0);
  std::ifstream in(log);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("exists and is not a folder"), std::string::npos) << text;
}

TEST(DemoRender, BadSizeIsRefused) {
  EXPECT_NE(run(std::string(SINEW_DEMO) + " hello --frames 1 --size 10xx --render " + out_dir("bad").string()), 0);
}

// The number of frames ffprobe counts in a video, or -1 when it cannot read one.
int video_frames(const fs::path& file) {
  const std::string command =
      "ffprobe -v error -count_frames -select_streams v:0 -show_entries stream=nb_read_frames -of csv=p=0 '" +
      file.string() + "' 2>/dev/null";
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return -1;
  int n = -1;
  if (std::fscanf(pipe, "%d", &n) != 1) n = -1;
  pclose(pipe);
  return n;
}

TEST(DemoVideo, AssemblesAnMp4AndAGif) {
  if (run("command -v ffmpeg") != 0) GTEST_SKIP() << "ffmpeg is not installed (.ci/deps installs it)";
  const fs::path dir = out_dir("video");
  ASSERT_EQ(run(std::string(SINEW_DEMO) + " hello --frames 6 --size 160x90 --video " + (dir / "hello.mp4").string()),
            0);
  ASSERT_TRUE(fs::exists(dir / "hello.mp4"));
  EXPECT_EQ(head(dir / "hello.mp4", 8).substr(4), "ftyp") << "not an MP4 file";
  EXPECT_EQ(video_frames(dir / "hello.mp4"), 6);
  ASSERT_EQ(run(std::string(SINEW_DEMO) + " hello --frames 6 --size 160x90 --video " + (dir / "hello.gif").string()),
            0);
  EXPECT_EQ(head(dir / "hello.gif", 6), "GIF89a");
}

// A folder that held a longer run's frames: the video has this run's frames only.
TEST(DemoVideo, HasThisRunsFramesOnly) {
  if (run("command -v ffprobe") != 0) GTEST_SKIP() << "ffmpeg is not installed (.ci/deps installs it)";
  const fs::path dir = out_dir("stale");
  ASSERT_EQ(run(std::string(SINEW_DEMO) + " hello --frames 6 --size 64x48 --render " + (dir / "frames").string()), 0);
  ASSERT_EQ(run(std::string(SINEW_DEMO) + " hello --frames 3 --size 64x48 --render " + (dir / "frames").string() +
                " --video " + (dir / "three.mp4").string()),
            0);
  EXPECT_EQ(video_frames(dir / "three.mp4"), 3);
}

TEST(DemoVideo, MissingFfmpegIsNamed) {
  const fs::path dir = out_dir("no-ffmpeg");
  const std::string log = (dir / "log.txt").string();
  // With an empty PATH the shell finds no ffmpeg.
  const int status =
      std::system(("PATH=/nonexistent " + std::string(SINEW_DEMO) + " hello --frames 1 --size 64x64 --video " +
                   (dir / "x.mp4").string() + " > " + log + " 2>&1")
                      .c_str());
  EXPECT_NE(status, 0);
  std::ifstream in(log);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("ffmpeg is not installed"), std::string::npos) << text;
}

// The viewer opens a window on a virtual display, runs 20 frames, saves what it shows and exits.
TEST(Viewer, RunsUnderXvfbAndTakesAScreenshot) {
  if (run("command -v xvfb-run") != 0) GTEST_SKIP() << "xvfb-run is not installed (.ci/deps installs xvfb)";
  const fs::path dir = out_dir("viewer");
  const fs::path shot = dir / "curtain.png";
  ASSERT_EQ(run("xvfb-run -a -s '-screen 0 1024x768x24' " + std::string(SINEW_VIEW) +
                " curtain --size 480x270 --frames 20 --screenshot " + shot.string()),
            0);
  expect_picture(shot, 480, 270);
}

TEST(Viewer, UnknownSceneIsNamed) {
  const fs::path dir = out_dir("viewer-bad");
  const std::string log = (dir / "log.txt").string();
  const int status = std::system((std::string(SINEW_VIEW) + " drapes > " + log + " 2>&1").c_str());
  EXPECT_NE(status, 0);
  std::ifstream in(log);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("unknown scene 'drapes'"), std::string::npos) << text;
}

}  // namespace
}  // namespace sinew
