// Job: the HuMem harness's headless monocular driver for patched ORB-SLAM3
// v1.0. It feeds an image folder to ORB_SLAM3::System (viewer off) at a
// fixed rate (never ahead of Local Mapping, see --realtime), with the HuMem plugin or plain DBoW2 as the settings YAML
// chooses (HuMem.Address / HuMem.Enabled), waits for Local Mapping and Loop
// Closing to finish their queues, and writes into --out:
//   keyframes.txt      every live keyframe at the end, as ORB-SLAM3 holds it:
//                      source image index, keyframe id (mnId), frame id, map id,
//                      timestamp, T_wc (tx ty tz qx qy qz qw)
//   keyframes_map<ID>.tum  the same per map, in TUM format
//   maps.txt           map id, keyframes, 1 for the active map
//   frames.txt         source index, timestamp, tracking state after the frame
//   counters.txt       the driver's and (with HuMem) the plugin's counters
// Loop, merge, relocalisation and candidate events are printed by the patch
// at Verbose level VERBOSE, which this driver turns on ("[ORB-SLAM3 event]").
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <dirent.h>

#include <opencv2/core/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "Atlas.h"
#include "KeyFrame.h"
#include "LocalMapping.h"
#include "LoopClosing.h"
#include "Map.h"
#include "System.h"
#include "VprKeyFrameDatabase.h"

namespace
{

struct Args
{
    std::string vocabulary, settings, images, out, timestamps;
    double fps;
    int maxFrames;
    bool realtime;
    Args() : fps(10.0), maxFrames(-1), realtime(false) {}
};

void Usage()
{
    std::cerr << "usage: humem_orbslam3_mono --vocabulary VOC.txt --settings SETTINGS.yaml --images DIR --out DIR\n"
                 "                           [--fps 10] [--timestamps POSES.txt (TUM: first column)] [--max-frames N]\n"
                 "                           [--realtime 1 (do not wait for Local Mapping)]\n";
}

bool Parse(int argc, char** argv, Args* a)
{
    for(int i = 1; i < argc; ++i)
    {
        std::string k = argv[i];
        if(i + 1 >= argc) { Usage(); return false; }
        std::string v = argv[++i];
        if(k == "--vocabulary") a->vocabulary = v;
        else if(k == "--settings") a->settings = v;
        else if(k == "--images") a->images = v;
        else if(k == "--out") a->out = v;
        else if(k == "--timestamps") a->timestamps = v;
        else if(k == "--fps") a->fps = atof(v.c_str());
        else if(k == "--max-frames") a->maxFrames = atoi(v.c_str());
        else if(k == "--realtime") a->realtime = atoi(v.c_str()) != 0;
        else { Usage(); return false; }
    }
    if(a->vocabulary.empty() || a->settings.empty() || a->images.empty() || a->out.empty() || a->fps <= 0)
    {
        Usage();
        return false;
    }
    return true;
}

// The folder's .jpg/.jpeg/.png files, sorted by name (000000.jpg, ...).
std::vector<std::string> ListImages(const std::string &dir)
{
    std::vector<std::string> names;
    DIR* d = opendir(dir.c_str());
    if(!d)
        return names;
    while(struct dirent* e = readdir(d))
    {
        std::string n = e->d_name;
        std::string lower = n;
        std::transform(lower.begin(), lower.end(), lower.begin(), ::tolower);
        const size_t dot = lower.rfind('.');
        if(dot == std::string::npos)
            continue;
        const std::string ext = lower.substr(dot);
        if(ext == ".jpg" || ext == ".jpeg" || ext == ".png")
            names.push_back(n);
    }
    closedir(d);
    std::sort(names.begin(), names.end());
    return names;
}

// First column of a TUM file (comments skipped).
std::vector<double> ReadTimestamps(const std::string &path)
{
    std::vector<double> ts;
    std::ifstream f(path.c_str());
    std::string line;
    while(std::getline(f, line))
    {
        if(line.empty() || line[0] == '#')
            continue;
        std::istringstream s(line);
        double t;
        if(s >> t)
            ts.push_back(t);
    }
    return ts;
}

// Waits until cond() holds or timeout_s passes; false on timeout.
template <typename F>
bool WaitUntil(F cond, double timeout_s)
{
    const std::chrono::steady_clock::time_point end =
        std::chrono::steady_clock::now() + std::chrono::milliseconds(static_cast<long>(timeout_s * 1000));
    while(!cond())
    {
        if(std::chrono::steady_clock::now() > end)
            return false;
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return true;
}

} // namespace

int main(int argc, char** argv)
{
    Args a;
    if(!Parse(argc, argv, &a))
        return 2;
    const std::vector<std::string> names = ListImages(a.images);
    if(names.empty())
    {
        std::cerr << "no images in " << a.images << std::endl;
        return 1;
    }
    size_t n = names.size();
    if(a.maxFrames >= 0 && static_cast<size_t>(a.maxFrames) < n)
        n = static_cast<size_t>(a.maxFrames);
    std::vector<double> ts;
    if(!a.timestamps.empty())
    {
        ts = ReadTimestamps(a.timestamps);
        if(ts.size() < n)
        {
            std::cerr << a.timestamps << " has " << ts.size() << " timestamps for " << n << " images" << std::endl;
            return 1;
        }
    }
    else
        for(size_t i = 0; i < n; ++i)
            ts.push_back(static_cast<double>(i) / a.fps);
    std::map<double, size_t> indexOf;  // timestamp -> source image index
    for(size_t i = 0; i < n; ++i)
        indexOf[ts[i]] = i;

    ORB_SLAM3::System SLAM(a.vocabulary, a.settings, ORB_SLAM3::System::MONOCULAR, false);
    // The patch's event lines ("[ORB-SLAM3 event] ...") are at level VERBOSE
    // (after the constructor, which sets the level to QUIET).
    ORB_SLAM3::Verbose::SetTh(ORB_SLAM3::Verbose::VERBOSITY_VERBOSE);

    // Feed the frames at a fixed rate: frame i is due at start + i / fps.
    // Unless --realtime 1, a frame also waits until Local Mapping is idle
    // (its queue empty, no keyframe in work): on a loaded machine a real-time feed
    // outruns Local Mapping and tracking fails for reasons that have nothing
    // to do with place recognition (on 2 busy cores most frames were lost).
    ORB_SLAM3::LocalMapping* lm = SLAM.GetLocalMapper();
    ORB_SLAM3::LoopClosing* lc = SLAM.GetLoopCloser();
    double paceStart = 0;
    std::ofstream frames((a.out + "/frames.txt").c_str());
    frames << "# index timestamp state (ORB-SLAM3 tracking state after the frame: 1 not initialised, 2 ok, "
              "3 recently lost, 4 lost)\n";
    size_t framesLost = 0;
    const std::chrono::steady_clock::time_point t0 = std::chrono::steady_clock::now();
    for(size_t i = 0; i < n; ++i)
    {
        cv::Mat im = cv::imread(a.images + "/" + names[i], cv::IMREAD_UNCHANGED);
        if(im.empty())
        {
            std::cerr << "cannot read " << names[i] << std::endl;
            return 1;
        }
        if(!a.realtime)
        {
            const std::chrono::steady_clock::time_point w0 = std::chrono::steady_clock::now();
            // Idle: nothing queued and not processing one (AcceptKeyFrames is
            // false while Local Mapping works on a keyframe).
            WaitUntil([&]() { return lm->KeyframesInQueue() == 0 && lm->AcceptKeyFrames(); }, 10);
            paceStart += std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
        }
        SLAM.TrackMonocular(im, ts[i]);
        const int state = SLAM.GetTrackingState();
        if(state == ORB_SLAM3::Tracking::RECENTLY_LOST || state == ORB_SLAM3::Tracking::LOST)
            ++framesLost;
        frames << i << " " << std::fixed << std::setprecision(6) << ts[i] << " " << state << "\n";
        std::this_thread::sleep_until(t0 + std::chrono::microseconds(static_cast<long>((i + 1) * 1e6 / a.fps)) +
                                      std::chrono::microseconds(static_cast<long>(paceStart * 1e6)));
    }
    frames.close();
    const double feedSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

    // Let Local Mapping and Loop Closing finish what is queued (v1.0's
    // Shutdown does not wait), then stop them.
    bool drained = true;
    for(int pass = 0; pass < 2; ++pass)  // twice: loop closing can start a global BA
    {
        // Local Mapping idle (queue empty, no keyframe in work: its last BA
        // moves keyframes, and Loop Closing's add of that keyframe is what
        // sends the moved poses) and Loop Closing's queue empty.
        drained = WaitUntil([&]() {
            return lm->KeyframesInQueue() == 0 && lm->AcceptKeyFrames() && lc->KeyFramesInQueue() == 0;
        }, 120) && drained;
        std::this_thread::sleep_for(std::chrono::milliseconds(1000));
        drained = WaitUntil([&]() { return !lc->isRunningGBA(); }, 300) && drained;
    }
    SLAM.Shutdown();
    const bool finished = WaitUntil([&]() { return lm->isFinished() && lc->isFinished(); }, 60);
    if(!drained || !finished)
        std::cout << "[harness] warning: local mapping / loop closing did not finish in time" << std::endl;

    // Every live keyframe as ORB-SLAM3 holds it.
    ORB_SLAM3::Atlas* atlas = SLAM.GetAtlas();
    ORB_SLAM3::Map* current = atlas->GetCurrentMap();
    std::vector<ORB_SLAM3::Map*> maps = atlas->GetAllMaps();
    std::ofstream kfs((a.out + "/keyframes.txt").c_str());
    std::ofstream mapsOut((a.out + "/maps.txt").c_str());
    kfs << "# index kf_id frame_id map_id timestamp tx ty tz qx qy qz qw (T_wc, camera to map)\n";
    mapsOut << "# map_id keyframes active\n";
    size_t liveKFs = 0;
    for(size_t m = 0; m < maps.size(); ++m)
    {
        ORB_SLAM3::Map* pMap = maps[m];
        if(!pMap || pMap->IsBad())
            continue;
        std::vector<ORB_SLAM3::KeyFrame*> vpKFs = pMap->GetAllKeyFrames();
        std::sort(vpKFs.begin(), vpKFs.end(), ORB_SLAM3::KeyFrame::lId);
        std::ostringstream tumName;
        tumName << a.out << "/keyframes_map" << pMap->GetId() << ".tum";
        std::ofstream tum(tumName.str().c_str());
        size_t count = 0;
        for(size_t k = 0; k < vpKFs.size(); ++k)
        {
            ORB_SLAM3::KeyFrame* pKF = vpKFs[k];
            if(!pKF || pKF->isBad())
                continue;
            const Sophus::SE3f Twc = pKF->GetPoseInverse();
            const Eigen::Vector3f t = Twc.translation();
            const Eigen::Quaternionf q = Twc.unit_quaternion();
            std::map<double, size_t>::const_iterator it = indexOf.find(pKF->mTimeStamp);
            const long index = it == indexOf.end() ? -1L : static_cast<long>(it->second);
            std::ostringstream pose;
            pose << std::setprecision(9) << t.x() << " " << t.y() << " " << t.z() << " " << q.x() << " " << q.y()
                 << " " << q.z() << " " << q.w();
            kfs << index << " " << pKF->mnId << " " << pKF->mnFrameId << " " << pMap->GetId() << " " << std::fixed
                << std::setprecision(6) << pKF->mTimeStamp << " " << pose.str() << "\n";
            tum << std::fixed << std::setprecision(6) << pKF->mTimeStamp << " " << pose.str() << "\n";
            ++count;
        }
        liveKFs += count;
        mapsOut << pMap->GetId() << " " << count << " " << (pMap == current ? 1 : 0) << "\n";
    }
    kfs.close();
    mapsOut.close();

    std::ofstream counters((a.out + "/counters.txt").c_str());
    counters << "frames " << n << "\nframes_lost " << framesLost << "\nfeed_seconds " << feedSeconds << "\nwaited_for_local_mapping_seconds " << paceStart
             << "\nkeyframes " << liveKFs << "\nmaps " << maps.size() << "\ndrained " << (drained && finished ? 1 : 0)
             << "\n";
    ORB_SLAM3::VprKeyFrameDatabase* vpr = dynamic_cast<ORB_SLAM3::VprKeyFrameDatabase*>(SLAM.GetKeyFrameDatabase());
    if(vpr)
    {
        // Every write acknowledged before the server is stopped and exported.
        const humem::Status flushed = vpr->Flush(std::chrono::milliseconds(30000));
        vpr->LogCounters();
        const ORB_SLAM3::VprKeyFrameDatabase::Counters c = vpr->GetCounters();
        counters << "humem 1\nhumem_flushed " << (flushed.ok() ? 1 : 0) << "\nhumem_inserts " << c.inserts
                 << "\nhumem_inserts_no_image " << c.insertsNoImage << "\nhumem_inserts_refused " << c.insertsRefused
                 << "\nhumem_erases " << c.erases << "\nhumem_map_resets " << c.mapResets << "\nhumem_session_resets "
                 << c.sessionResets << "\nhumem_pose_updates " << c.poseUpdates << "\nhumem_poses_sent "
                 << c.posesSent << "\nhumem_loop_queries " << c.loopQueries << "\nhumem_loop_answered "
                 << c.loopAnswered << "\nhumem_loop_not_answered " << c.loopNotAnswered << "\nhumem_loop_candidates "
                 << c.loopCandidates << "\nhumem_loop_used " << c.loopUsed << "\nhumem_merge_used " << c.mergeUsed
                 << "\nhumem_reloc_queries " << c.relocQueries << "\nhumem_reloc_answers_used " << c.relocAnswersUsed
                 << "\nhumem_reloc_candidates " << c.relocCandidates << "\nhumem_write_failures " << c.writeFailures
                 << "\nhumem_verdicts_reported " << c.verdictsReported << "\nhumem_verdicts_accepted " << c.verdictsAccepted
                 << "\nhumem_verdicts_not_humem " << c.verdictsNotHuMem << "\nhumem_verdicts_skipped " << c.verdictsSkipped
                 << "\nhumem_extra_coincidences " << c.extraCoincidences
                 << "\n";
    }
    else
        counters << "humem 0\n";
    counters.close();
    std::cout << "[harness] " << n << " frames in " << std::fixed << std::setprecision(1) << feedSeconds << " s, "
              << liveKFs << " keyframes in " << maps.size() << " maps; output in " << a.out << std::endl;
    std::cout.flush();
    // ORB-SLAM3's threads and the HuMem client are never torn down; skip
    // static destructors that would race them.
    _exit(0);
}
