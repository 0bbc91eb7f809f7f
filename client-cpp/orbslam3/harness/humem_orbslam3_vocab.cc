// Job: trains an ORB vocabulary for ORB-SLAM3 v1.0 with ORB-SLAM3's own
// ORBextractor and DBoW2 (ORBvoc.txt ships in no package registry). The
// features are extracted as Tracking extracts them (1000 ORB features, 8
// levels, scale 1.2, FAST 20/7), the tree is built by DBoW2's
// TemplatedVocabulary::create (k-means++ per node, TF-IDF weights, L1 score,
// like ORBvoc.txt) and saved with saveToTextFile, so ORB-SLAM3 loads it like
// ORBvoc.txt.
//
//   humem_orbslam3_vocab --out voc.txt [--k 10] [--l 5] [--max-images 400] [--features 1000] DIR...
//
// Train it on images that are NOT the ones you evaluate on.
#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include <dirent.h>

#include <opencv2/core/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc/imgproc.hpp>

#include "ORBVocabulary.h"
#include "ORBextractor.h"

namespace
{

std::vector<std::string> ListImages(const std::string &dir)
{
    std::vector<std::string> paths;
    DIR* d = opendir(dir.c_str());
    if(!d)
        return paths;
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
            paths.push_back(dir + "/" + n);
    }
    closedir(d);
    std::sort(paths.begin(), paths.end());
    return paths;
}

} // namespace

int main(int argc, char** argv)
{
    std::string out;
    int k = 10, l = 5, maxImages = 400, nFeatures = 1000;
    std::vector<std::string> dirs;
    for(int i = 1; i < argc; ++i)
    {
        std::string a = argv[i];
        if((a == "--out" || a == "--k" || a == "--l" || a == "--max-images" || a == "--features") && i + 1 < argc)
        {
            std::string v = argv[++i];
            if(a == "--out") out = v;
            else if(a == "--k") k = atoi(v.c_str());
            else if(a == "--l") l = atoi(v.c_str());
            else if(a == "--max-images") maxImages = atoi(v.c_str());
            else nFeatures = atoi(v.c_str());
        }
        else
            dirs.push_back(a);
    }
    if(out.empty() || dirs.empty() || k < 2 || l < 1)
    {
        std::cerr << "usage: humem_orbslam3_vocab --out voc.txt [--k 10] [--l 5] [--max-images 400] [--features 1000] DIR...\n";
        return 2;
    }

    std::vector<std::string> paths;
    for(size_t i = 0; i < dirs.size(); ++i)
    {
        std::vector<std::string> p = ListImages(dirs[i]);
        paths.insert(paths.end(), p.begin(), p.end());
    }
    // At most maxImages, evenly spaced over all folders.
    if(maxImages > 0 && paths.size() > static_cast<size_t>(maxImages))
    {
        std::vector<std::string> kept;
        for(int i = 0; i < maxImages; ++i)
            kept.push_back(paths[static_cast<size_t>(static_cast<double>(i) * paths.size() / maxImages)]);
        paths.swap(kept);
    }
    if(paths.empty())
    {
        std::cerr << "no images found\n";
        return 1;
    }

    // Tracking's extractor settings (ORBextractor.* of the harness settings).
    ORB_SLAM3::ORBextractor extractor(nFeatures, 1.2f, 8, 20, 7);
    std::vector<std::vector<cv::Mat> > features;
    features.reserve(paths.size());
    size_t total = 0;
    const std::chrono::steady_clock::time_point t0 = std::chrono::steady_clock::now();
    for(size_t i = 0; i < paths.size(); ++i)
    {
        cv::Mat im = cv::imread(paths[i], cv::IMREAD_GRAYSCALE);
        if(im.empty())
        {
            std::cerr << "cannot read " << paths[i] << "\n";
            continue;
        }
        std::vector<cv::KeyPoint> keys;
        cv::Mat desc;
        std::vector<int> lapping(2, 0);
        extractor(im, cv::Mat(), keys, desc, lapping);
        std::vector<cv::Mat> rows;
        rows.reserve(desc.rows);
        for(int r = 0; r < desc.rows; ++r)
            rows.push_back(desc.row(r).clone());
        total += rows.size();
        features.push_back(rows);
    }
    const double extractS = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::cout << "extracted " << total << " ORB descriptors from " << features.size() << " images in " << extractS
              << " s" << std::endl;

    ORB_SLAM3::ORBVocabulary voc(k, l, DBoW2::TF_IDF, DBoW2::L1_NORM);
    voc.create(features);
    const double trainS = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() - extractS;
    std::cout << "vocabulary: k " << k << ", L " << l << ", " << voc.size() << " words, trained in " << trainS << " s"
              << std::endl;
    voc.saveToTextFile(out);
    std::cout << "saved " << out << std::endl;
    return 0;
}
